"""Settings: defaults, the three sources and their precedence, and refusals that name the problem."""

from __future__ import annotations

import argparse

import pytest

from common import settings as config


def load(argv=(), env=None, toml: str | None = None, tmp_path=None):
    parser = argparse.ArgumentParser()
    config.add_arguments(parser)
    args = parser.parse_args(list(argv))
    environ = dict(env or {})
    if toml is not None:
        path = tmp_path / "gateway.toml"
        path.write_text(toml)
        environ["SOVD_CONFIG"] = str(path)
    return config.load(args, environ)


def test_defaults_match_the_architecture_table():
    cfg = load()
    assert (cfg.sample_timeout, cfg.max_pool_size, cfg.cold_wait_cap, cfg.idle_safety_net,
            cfg.idle_sweep_tick, cfg.max_queue_depth, cfg.watchdog_threshold, cfg.graph_poll_tick) == \
        (1.0, 256, 4, 900.0, 60.0, 256, 5000, 100)
    assert cfg.bind == "127.0.0.1:8080"
    assert cfg.allow_publish is False


def test_flags_win_over_environment_which_wins_over_the_file(tmp_path):
    cfg = load(["--max-pool-size", "30"], {"SOVD_MAX_POOL_SIZE": "20", "SOVD_SAMPLE_TIMEOUT": "2.5"},
               "max_pool_size = 10\nsample_timeout = 0.5\ncold_wait_cap = 0\n", tmp_path)
    assert cfg.max_pool_size == 30
    assert cfg.sample_timeout == 2.5
    assert cfg.cold_wait_cap == 0  # 0 = no cap is allowed below the range


def test_to_env_round_trips():
    cfg = load(["--allow-publish", "--workers", "3"])
    again = config.load(None, cfg.to_env())
    assert again == cfg


@pytest.mark.parametrize("argv, env, needle", [
    (["--sample-timeout", "0.01"], {}, "sample_timeout (from flag --sample-timeout): 0.01 is out of range"),
    (["--max-pool-size", "5000"], {}, "allowed: 1–4096"),
    ([], {"SOVD_COLD_WAIT_CAP": "-1"}, "cold_wait_cap (from environment SOVD_COLD_WAIT_CAP)"),
    ([], {"SOVD_MAX_POOL_SIZE": "many"}, "'many' is not a valid int"),
    ([], {"SOVD_SAMPLE_TIMEOUT": "nan"}, "is not a valid float"),
    ([], {"SOVD_ALLOW_PUBLISH": "perhaps"}, "is not a valid bool"),
    (["--bind", "localhost"], {}, "is not HOST:PORT"),
    (["--bind", "127.0.0.1:70000"], {}, "port of 1–65535"),
    (["--gateway-name", "9bad"], {}, "not a valid ROS node name"),
    (["--log-level", "loud"], {}, "one of debug, info, warning, error"),
    ([], {"SOVD_API_TOKEN": "short"}, "at least 16 characters"),
    (["--api-token", "a-long-enough-secret"], {}, "never given as a flag"),
    (["--jwt-secret", "x" * 40], {}, "SOVD_JWT_SECRET"),
    (["--auth-clients", "a:b:admin"], {}, "never given as a flag"),
    ([], {"SOVD_AUTH_ENABLED": "1", "SOVD_AUTH_CLIENTS": "a:b:admin", "SOVD_JWT_SECRET": "short"}, "32 characters"),
    ([], {"SOVD_AUTH_ENABLED": "1", "SOVD_JWT_SECRET": "x" * 32}, "auth_clients"),
    ([], {"SOVD_AUTH_CLIENTS": "a:b:superuser"}, "viewer, operator, configurator, admin"),
    ([], {"SOVD_AUTH_CLIENTS": "a:b:admin,a:c:viewer"}, "given twice"),
    ([], {"SOVD_AUTH_CLIENTS": "a::admin"}, "empty secret"),
    ([], {"SOVD_AUTH_CLIENTS": "just-a-name"}, "id:secret:role"),
    (["--require-auth-for", "some"], {}, "none, write, all"),
    (["--tls-cert", "/etc/hostname"], {}, "give both"),
    (["--tls-cert", "/nope.pem", "--tls-key", "/nope.key"], {}, "not a readable file"),
    ([], {"SOVD_AUTH_ENABLED": "1", "SOVD_AUTH_CLIENTS": "a:b:admin", "SOVD_JWT_ALGORITHM": "RS256",
          "SOVD_JWT_SECRET": "/nope.pem"}, "RS256 needs a readable PEM file"),
    (["--token-expiry-seconds", "100", "--refresh-token-expiry-seconds", "50"], {"SOVD_AUTH_ENABLED": "1",
     "SOVD_AUTH_CLIENTS": "a:b:admin", "SOVD_JWT_SECRET": "x" * 32}, "at least token_expiry_seconds"),
])
def test_out_of_range_values_are_refused_with_a_clear_message(argv, env, needle):
    with pytest.raises(config.ConfigError) as info:
        load(argv, env)
    assert needle in str(info.value)


def test_config_file_errors_name_the_file_and_key(tmp_path):
    with pytest.raises(config.ConfigError, match="unknown setting 'max_pool'"):
        load(toml="max_pool = 3\n", tmp_path=tmp_path)
    with pytest.raises(config.ConfigError, match="not valid TOML"):
        load(toml="max_pool_size = = 3\n", tmp_path=tmp_path)
    with pytest.raises(config.ConfigError, match="config file .*: 0 is out of range"):
        load(toml="max_pool_size = 0\n", tmp_path=tmp_path)


def test_runtime_dir_is_created_private(tmp_path):
    path = tmp_path / "rt"
    config.ensure_runtime_dir(str(path))
    assert path.stat().st_mode & 0o777 == 0o700
    path.chmod(0o755)
    config.ensure_runtime_dir(str(path))
    assert path.stat().st_mode & 0o777 == 0o700


def test_worker_connections_replaces_threads_which_is_ignored_from_every_source(tmp_path):
    assert load().worker_connections == 1000
    assert load(["--worker-connections", "64"]).worker_connections == 64
    with pytest.raises(config.ConfigError, match="worker_connections .*out of range"):
        load(["--worker-connections", "0"])
    cfg = load(["--threads", "4"], {"SOVD_THREADS": "8"}, "threads = 2\nworkers = 3\n", tmp_path)
    assert cfg.workers == 3 and "threads" not in cfg
    assert [note.split(" is no longer")[0] for note in cfg.ignored] == [
        f"threads (from config file {tmp_path / 'gateway.toml'})", "threads (from environment SOVD_THREADS)",
        "threads (from flag --threads)"]
    assert all("worker_connections" in note for note in cfg.ignored)
    assert "SOVD_THREADS" not in cfg.to_env()
    assert load().ignored == ()


def test_fleet_settings_are_off_by_default_and_work_from_every_source(tmp_path):
    cfg = load()
    assert (cfg.cors_origins, cfg.rate_limit, cfg.rate_limit_global, cfg.access_log) == ("", "", "", False)
    assert config.parse_rate(cfg.rate_limit) is None and config.parse_origins(cfg.cors_origins) is None
    cfg = load(["--rate-limit", "50/100", "--access-log"], {"SOVD_RATE_LIMIT_GLOBAL": "200/400"},
               'cors_origins = "https://ui.example:8443, http://localhost:3000"\n', tmp_path)
    assert config.parse_rate(cfg.rate_limit) == config.Rate(50.0, 100)
    assert config.parse_rate(cfg.rate_limit_global) == config.Rate(200.0, 400)
    assert config.parse_rate("2.5") == config.Rate(2.5, 3)  # no burst: the rate, rounded up
    assert config.parse_origins(cfg.cors_origins) == ("https://ui.example:8443", "http://localhost:3000")
    assert config.parse_origins("*") == "*"
    # An IPv6 literal as a browser writes it in Origin: lower case, zeros compressed.
    assert config.parse_origins("http://[FD00:0:0::10]:8443,https://[::1]") == (
        "http://[fd00::10]:8443", "https://[::1]")
    assert cfg.access_log is True
    assert config.load(None, cfg.to_env()) == cfg


@pytest.mark.parametrize("argv, env, needle", [
    (["--rate-limit", "fast"], {}, "rate_limit (from flag --rate-limit): 'fast' is not RATE/BURST"),
    ([], {"SOVD_RATE_LIMIT_GLOBAL": "0/10"}, "rate_limit_global (from environment SOVD_RATE_LIMIT_GLOBAL): "
                                              "rate 0 is out of range"),
    (["--rate-limit", "5/0"], {}, "burst 0 is out of range"),
    ([], {"SOVD_RATE_LIMIT": "-5/10"}, "is not RATE/BURST"),
    (["--cors-origins", "https://ui.example/"], {}, "cors_origins (from flag --cors-origins): "
                                                     "'https://ui.example/' is not an origin"),
    (["--cors-origins", "*.example.com"], {}, "is not an origin"),
    (["--cors-origins", "*,https://ui.example"], {}, "give it alone"),
    (["--cors-origins", "ftp://ui.example"], {}, "with http or https"),
    (["--cors-origins", "http://[fd00:::10]:8443"], {}, "[fd00:::10] is not an IPv6 address"),
    ([], {"SOVD_ACCESS_LOG": "sometimes"}, "is not a valid bool"),
])
def test_fleet_settings_refuse_bad_values_naming_the_source(argv, env, needle):
    with pytest.raises(config.ConfigError) as info:
        load(argv, env)
    assert needle in str(info.value)


def test_every_setting_is_in_the_settings_reference():
    """docs/settings.md has one row per setting: its flag, its variable, its default."""
    from common.harness.procs import REPO

    rows = {line.split("|")[2].strip(" `"): [c.strip() for c in line.split("|")]
            for line in (REPO / "docs" / "settings.md").read_text().splitlines() if line.startswith("| `--")
            or line.startswith("| — (a secret)")}
    for s in config.SETTINGS:
        assert s.env in rows, f"{s.env} is not in docs/settings.md"
        # a secret has no flag (ps shows a command line); every other setting its own
        expected = "— (a secret)" if s.secret else f"`{s.flag}`"
        assert rows[s.env][1].startswith(expected), (s.flag, rows[s.env])
    assert len(rows) == len(config.SETTINGS), set(rows) - {s.env for s in config.SETTINGS}


# ---- the fleet over Zenoh (issue 34) -------------------------------------------------------------------
TOKEN = ["--api-token", "t" * 16]  # a secret: fleet_load puts it in the environment, where secrets go


def fleet_load(argv=(), env=None):
    argv = list(argv)
    env = dict(env or {})
    if "--api-token" in argv:
        at = argv.index("--api-token")
        env["SOVD_API_TOKEN"] = argv[at + 1]
        del argv[at:at + 2]
    return load(argv, env)


def test_the_zenoh_fleet_is_off_by_default_and_its_id_defaults_to_the_host_name(monkeypatch):
    cfg = fleet_load()
    assert (cfg.fleet_link, cfg.fleet_aggregate, cfg.fleet_allow_writes, cfg.fleet_id) == (False, False, False, "")
    assert (cfg.fleet_timeout, cfg.fleet_max_robots) == (2.0, 1000)
    import socket

    monkeypatch.setattr(socket, "gethostname", lambda: "Robot-7.Lab.example.com")
    cfg = fleet_load(["--fleet-link", "--fleet-connect", "tcp/10.0.0.1:7447", *TOKEN])
    assert cfg.fleet_id == "robot-7_lab_example_com"
    assert config.load(None, cfg.to_env()) == cfg          # the children see the same id
    assert config.default_fleet_id("__") == "robot" and config.default_fleet_id("a..b") == "a_b"
    cfg = fleet_load(["--fleet-aggregate", *TOKEN], {"SOVD_FLEET_CONNECT": "tls/fleet.example.com:7447"})
    assert cfg.fleet_aggregate and cfg.fleet_connect == "tls/fleet.example.com:7447"


@pytest.mark.parametrize("argv, needle", [
    (["--fleet-link", "--fleet-aggregate", "--fleet-connect", "tcp/h:1", *TOKEN], "turn one of them off"),
    (["--fleet-link", *TOKEN], "give fleet_connect"),
    (["--fleet-aggregate", "--fleet-connect", "tcp/h:1"], "set api_token"),
    (["--fleet-link", "--fleet-connect", "tcp/h:1", "--fleet-id", "a__b", *TOKEN], "'a__b' is not a fleet id"),
    (["--fleet-link", "--fleet-connect", "tcp/h:1", "--fleet-id", "a/b", *TOKEN], "is not a fleet id"),
    (["--fleet-link", "--fleet-zenoh-config", "/nonexistent.json5", *TOKEN], "is not a file"),
    (["--fleet-timeout", "0"], "fleet_timeout (from flag --fleet-timeout): 0.0 is out of range"),
    (["--fleet-max-robots", "0"], "out of range"),
])
def test_the_zenoh_fleet_refuses_settings_it_cannot_work_with(argv, needle):
    with pytest.raises(config.ConfigError) as info:
        fleet_load(argv)
    assert needle in str(info.value)
