"""``sovd-gateway``'s command line: flags, settings errors (exit 2), runtime dir creation."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import psutil
import pytest

from common.harness.gateway import Gateway
from common.harness.procs import REPO, Proc, free_port, poll_until
from supervisor import cli

BIN = Path(sys.executable).parent


def run_cli(*args: str, env: dict | None = None, timeout: float = 30) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "sovd-gateway"), *args], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO, env={**os.environ, **(env or {})})


def test_help_lists_the_operator_flags():
    r = run_cli("--help")
    assert r.returncode == 0
    for flag in ("--bind", "--runtime-dir", "--workers", "--allow-publish", "--sample-timeout",
                 "--config", "--log-level", "--watchdog-grace", "--restart-limit", "--shutdown-grace"):
        assert flag in r.stdout


def test_version():
    r = run_cli("--version")
    assert r.returncode == 0
    assert r.stdout.startswith("sovd-gateway ")


@pytest.mark.parametrize("args, env, words", [
    (["--workers", "0"], {}, ["workers", "flag --workers", "1–64"]),
    (["--workers", "two"], {}, ["workers", "not a valid int"]),
    (["--sample-timeout", "99"], {}, ["sample_timeout", "0.1–30"]),
    (["--bind", "nonsense"], {}, ["bind", "HOST:PORT"]),
    (["--bind", "127.0.0.1:70000"], {}, ["bind"]),
    (["--log-level", "loud"], {}, ["log_level", "debug, info, warning, error"]),
    ([], {"SOVD_RESTART_LIMIT": "0"}, ["restart_limit", "environment SOVD_RESTART_LIMIT"]),
    (["--api-token", "a-long-enough-secret"], {}, ["api_token", "never given as a flag", "SOVD_API_TOKEN"]),
])
def test_bad_settings_exit_2_with_a_clear_message(tmp_path, args, env, words):
    r = run_cli("--runtime-dir", str(tmp_path / "rt"), *args, env=env)
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith("sovd-gateway: error: ")
    for w in words:
        assert w in r.stderr
    assert not (tmp_path / "rt").exists()  # nothing was started or created


def test_config_file_errors_exit_2(tmp_path):
    missing = run_cli("--config", str(tmp_path / "nope.toml"))
    assert missing.returncode == 2 and "nope.toml" in missing.stderr
    bad = tmp_path / "bad.toml"
    bad.write_text("workers = 3\nno_such_setting = 1\n")
    r = run_cli("--config", str(bad))
    assert r.returncode == 2 and "unknown setting 'no_such_setting'" in r.stderr
    broken = tmp_path / "broken.toml"
    broken.write_text("workers = [\n")
    r = run_cli("--config", str(broken))
    assert r.returncode == 2 and "not valid TOML" in r.stderr


def test_unknown_flag_is_a_usage_error():
    r = run_cli("--no-such-flag")
    assert r.returncode == 2
    assert "unrecognized arguments" in r.stderr


def test_runtime_dir_that_cannot_be_created_exits_2(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    r = run_cli("--runtime-dir", str(blocker / "sub"))
    assert r.returncode == 2
    assert "runtime_dir" in r.stderr


def test_main_returns_2_in_process(capsys):
    assert cli.main(["--workers", "100"]) == 2
    assert "workers" in capsys.readouterr().err


def test_creates_the_runtime_dir_0700_and_honours_config_file_and_flags(tmp_path):
    """Config file < flag; the runtime dir is created private; the worker gets the settings.

    The file also names the retired ``threads``: start-up goes on, with a warning that names it.
    """
    conf = tmp_path / "gw.toml"
    conf.write_text("sample_timeout = 3.0\nworkers = 1\nworker_connections = 300\nthreads = 3\n")
    runtime = tmp_path / "run" / "sovd"
    port = free_port()
    gw = Proc([str(BIN / "sovd-gateway"), "--bind", f"127.0.0.1:{port}", "--runtime-dir", str(runtime),
               "--config", str(conf), "--sample-timeout", "1.5"], name="sovd-gateway")
    try:
        import requests

        poll_until(lambda: requests.get(f"http://127.0.0.1:{port}/api/v1/health", timeout=2).json()
                   ["x-medkit-subscription-executor"]["worker_alive"], 60, interval=0.2,
                   message="gateway healthy")
        assert os.stat(runtime).st_mode & 0o777 == 0o700
        worker = next(c for c in psutil.Process(gw.pid).children()
                      if "rosworker" in " ".join(c.cmdline()))
        env = worker.environ()
        assert env["SOVD_SAMPLE_TIMEOUT"] == "1.5"  # the flag beats the file
        assert env["SOVD_WORKER_CONNECTIONS"] == "300"  # from the file
        assert "SOVD_CONFIG" not in env             # children get resolved values only
        assert "SOVD_THREADS" not in env            # retired: not handed on
        assert any("threads (from config file" in line and "ignored" in line for line in gw.output), \
            "\n".join(gw.output[:20])
    finally:
        assert gw.stop() == 0


def test_gateway_helper_contract():
    """common/harness/gateway.py's contract: health reports worker_alive once started."""
    gw = Gateway("--workers", "1")
    try:
        r = gw.get("/health")
        assert r.status_code == 200
        assert r.json()["x-medkit-subscription-executor"]["worker_alive"] is True
    finally:
        assert gw.stop() == 0
