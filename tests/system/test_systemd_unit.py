"""systemd/sovd-gateway.service: the directives the service relies on, and ``systemd-analyze verify``."""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from common import settings as config
from common.harness.procs import REPO
from supervisor import cli, supervisor

UNIT = REPO / "systemd" / "sovd-gateway.service"
IN_CI = os.environ.get("CI", "").lower() == "true"


def parse_unit(text: str) -> dict[str, dict[str, list[str]]]:
    """Sections → key → every value (systemd allows a key several times)."""
    out: dict[str, dict[str, list[str]]] = {}
    section = None
    lines = iter(text.splitlines())
    for line in lines:
        line = line.strip()
        while line.endswith("\\"):
            line = line[:-1] + " " + next(lines).strip()
        if not line or line[0] in "#;":
            continue
        if line.startswith("["):
            section = line.strip("[]")
            out.setdefault(section, {})
            continue
        key, _, value = line.partition("=")
        out[section].setdefault(key.strip(), []).append(value.strip())
    return out


@pytest.fixture(scope="module")
def unit() -> dict[str, dict[str, list[str]]]:
    return parse_unit(UNIT.read_text())


def one(unit, key: str, section: str = "Service") -> str:
    values = unit[section].get(key)
    assert values, f"{key}= missing in [{section}]"
    return values[-1]


def seconds(text: str) -> float:
    text = text.strip()
    for suffix, factor in (("min", 60), ("ms", 0.001), ("s", 1), ("m", 60)):
        if text.endswith(suffix):
            return float(text[: -len(suffix)]) * factor
    return float(text)


def test_notify_and_watchdog(unit):
    assert one(unit, "Type") == "notify"
    assert one(unit, "NotifyAccess") == "main"
    watchdog = seconds(one(unit, "WatchdogSec"))
    defaults = {s.name: s.default for s in config.SETTINGS}
    # The supervisor must be able to replace a hung worker (threshold + grace + a restart)
    # within one watchdog period after its last ping (WatchdogSec/2 before).
    hang = defaults["watchdog_threshold"] / 1000 + defaults["watchdog_grace"] + 10
    assert watchdog / 2 + hang < watchdog


def test_restart_policy_matches_exit_codes(unit):
    assert one(unit, "Restart") == "on-failure"
    prevent = one(unit, "RestartPreventExitStatus").split()
    assert str(cli.EXIT_USAGE) in prevent and str(supervisor.EXIT_CANNOT_BOOT) in prevent
    assert str(supervisor.EXIT_FAILURE) not in prevent
    assert "StartLimitBurst" in unit["Unit"]


def test_stop_and_start_deadlines_cover_the_supervisor(unit):
    assert one(unit, "KillMode") == "mixed"
    defaults = {s.name: s.default for s in config.SETTINGS}
    stop = defaults["shutdown_grace"] + 1.5 + supervisor.WORKER_STOP_TIMEOUT + 2 * supervisor.KILL_WAIT
    assert seconds(one(unit, "TimeoutStopSec")) > stop
    assert seconds(one(unit, "TimeoutStartSec")) > supervisor.WORKER_BOOT_TIMEOUT + supervisor.HTTP_BOOT_TIMEOUT


def test_user_runtime_dir_and_environment(unit):
    assert one(unit, "User") == "sovd" and one(unit, "Group") == "sovd"
    assert one(unit, "RuntimeDirectory") == "sovd-gateway"
    assert one(unit, "RuntimeDirectoryMode") == "0700"
    # the store (faults.db: faults with their freeze frames, triggers) is the service user's alone
    assert one(unit, "StateDirectory") == "sovd-gateway" and one(unit, "StateDirectoryMode") == "0700"
    assert one(unit, "UMask") == "0077"
    assert one(unit, "EnvironmentFile") == "-/etc/default/sovd-gateway"
    # How to create the user is written down in the file.
    assert "useradd --system" in UNIT.read_text()


def test_exec_start_uses_the_venv_and_valid_flags(unit):
    argv = shlex.split(one(unit, "ExecStart"))
    assert argv[0] == "/opt/sovd-gateway/.venv/bin/sovd-gateway"
    args = cli.build_parser().parse_args(argv[1:])
    cfg = config.load(args, environ={})
    assert cfg.bind == "127.0.0.1:8080"


def test_hardening_without_breaking_dds(unit):
    service = unit["Service"]
    for key in ("NoNewPrivileges", "ProtectHome", "PrivateTmp", "PrivateDevices",
                "ProtectKernelTunables", "ProtectKernelModules", "ProtectKernelLogs",
                "ProtectControlGroups", "RestrictNamespaces", "LockPersonality", "RestrictRealtime",
                "RestrictSUIDSGID"):
        assert one(unit, key) == "yes", key
    assert one(unit, "ProtectSystem") == "strict"
    assert one(unit, "SystemCallArchitectures") == "native"
    assert one(unit, "CapabilityBoundingSet") == ""
    families = one(unit, "RestrictAddressFamilies").split()
    assert set(families) == {"AF_UNIX", "AF_INET", "AF_INET6", "AF_NETLINK"}
    # DDS needs the host network (UDP multicast) and shared memory.
    assert "PrivateNetwork" not in service
    assert "IPAddressDeny" not in service
    assert "PrivateIPC" not in service


def test_systemd_analyze_verify(tmp_path):
    tool = shutil.which("systemd-analyze")
    if tool is None:
        if IN_CI:
            pytest.fail("systemd-analyze is missing: .ci/run installs Debian's systemd package")
        pytest.skip("systemd-analyze not installed (apt-get install systemd)")
    # verify checks that ExecStart exists: point it at the real console script of this venv.
    real = Path(sys.executable).parent / "sovd-gateway"
    assert real.exists()
    text = UNIT.read_text().replace("/opt/sovd-gateway/.venv/bin/sovd-gateway", str(real))
    copy = tmp_path / "sovd-gateway.service"
    copy.write_text(text)
    r = subprocess.run([tool, "verify", str(copy)], capture_output=True, text=True, timeout=60,
                       env={**os.environ, "SYSTEMD_LOG_LEVEL": "notice"})
    complaints = [line for line in (r.stdout + r.stderr).splitlines() if str(copy) in line
                  or "sovd-gateway.service" in line]
    assert r.returncode == 0, r.stdout + r.stderr
    # verify exits 0 even for unknown keys or unparsable values; it names the file then.
    assert not complaints, "\n".join(complaints)


def test_verify_would_catch_a_mistake(tmp_path):
    """The check above is not vacuous: a typo in a directive is reported."""
    tool = shutil.which("systemd-analyze")
    if tool is None:
        pytest.skip("systemd-analyze not installed")
    real = Path(sys.executable).parent / "sovd-gateway"
    text = UNIT.read_text().replace("/opt/sovd-gateway/.venv/bin/sovd-gateway", str(real))
    copy = tmp_path / "sovd-gateway.service"
    copy.write_text(text.replace("ProtectHome=yes", "ProtectHomme=yes"))
    r = subprocess.run([tool, "verify", str(copy)], capture_output=True, text=True, timeout=60)
    assert "ProtectHomme" in r.stdout + r.stderr


def test_the_prometheus_example_scrapes_the_default_bind_at_metrics():
    import yaml

    example = yaml.safe_load((REPO / "systemd" / "prometheus-sovd-gateway.yml").read_text())
    job = example["scrape_configs"][0]
    assert job["metrics_path"] == "/metrics"
    assert job["static_configs"][0]["targets"] == [config.BY_NAME["bind"].default]
    # A scrape answers within ipc_timeout even with the ROS worker down: the timeout leaves room.
    assert float(job["scrape_timeout"].rstrip("s")) > config.BY_NAME["ipc_timeout"].default
