"""Every setting of the gateway: one table, three sources, one validation.

A setting comes from (lowest to highest precedence) its default, the TOML
config file (``--config FILE`` or ``SOVD_CONFIG``), the environment
(``SOVD_<NAME>``) and the command line (``--name-with-dashes``).  Values
outside their range are refused with a message that names the setting, the
source and the allowed range; nothing is silently clamped.

The supervisor resolves the settings once and hands them to its children as
``SOVD_*`` environment variables, so the ROS worker and every HTTP worker see
exactly the same values.

This module imports nothing heavy: the ROS worker, the HTTP workers and the
probe all import it.
"""

from __future__ import annotations

import argparse
import ipaddress
import math
import os
import re
import tempfile
import tomllib
from dataclasses import dataclass
from typing import Any

ENV_PREFIX = "SOVD_"
# Set by the supervisor for a restarted ROS worker, besides its settings: the attempt number
# (absent at the first boot).  A restarted worker waits a while for the runtime dir's lock
# (its predecessor may still be dying).
RESTART_ENV = "SOVD_WORKER_RESTART"
ACCESS_LOG_RATE = 100.0     # access lines per second, all HTTP workers together (app/core/accesslog.py)
ACCESS_LOG_BURST = 1000     # access lines at once before the rate applies
RATE_MAX = 1_000_000.0      # bounds of a RATE/BURST setting
BURST_MAX = 1_000_000


class ConfigError(ValueError):
    """A setting has a value that cannot be used; the message says which and why."""


@dataclass(frozen=True)
class Setting:
    name: str
    kind: type
    default: Any
    help: str
    low: float | None = None
    high: float | None = None
    zero_means: str | None = None  # e.g. "off": 0 is allowed below `low`
    choices: tuple[str, ...] | None = None
    secret: bool = False  # from the config file or the environment only: never a flag, which ps shows

    @property
    def env(self) -> str:
        return ENV_PREFIX + self.name.upper()

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")

    def range_text(self) -> str:
        if self.choices:
            return "one of " + ", ".join(self.choices)
        if self.low is None:
            return ""
        fmt = (lambda x: str(int(x))) if self.kind is int else (lambda x: f"{x:g}")
        text = f"{fmt(self.low)}–{fmt(self.high)}"
        if self.zero_means:
            text += f", or 0 = {self.zero_means}"
        return text

    def parse(self, raw: Any, source: str) -> Any:
        where = f"{self.name} (from {source})"
        try:
            value = _coerce(self.kind, raw)
        except (TypeError, ValueError):
            raise ConfigError(
                f"{where}: {raw!r} is not a valid {self.kind.__name__}"
                + (f" (allowed: {self.range_text()})" if self.range_text() else "")
            ) from None
        if self.choices and value not in self.choices:
            raise ConfigError(f"{where}: {value!r} is not {self.range_text()}")
        if self.low is not None and not (self.zero_means and value == 0):
            if not (self.low <= value <= self.high):
                raise ConfigError(f"{where}: {value!r} is out of range (allowed: {self.range_text()})")
        return value


def _coerce(kind: type, raw: Any) -> Any:
    if kind is bool:
        if isinstance(raw, bool):
            return raw
        text = str(raw).strip().lower()
        if text in ("1", "true", "yes", "on"):
            return True
        if text in ("0", "false", "no", "off", ""):
            return False
        raise ValueError(raw)
    if kind is int:
        if isinstance(raw, bool) or (isinstance(raw, float) and not raw.is_integer()):
            raise ValueError(raw)
        return int(str(raw).strip()) if isinstance(raw, str) else int(raw)
    if kind is float:
        if isinstance(raw, bool):
            raise ValueError(raw)
        value = float(raw)
        if value != value or value in (float("inf"), float("-inf")):
            raise ValueError(raw)
        return value
    if isinstance(raw, list) and all(isinstance(item, str) for item in raw):
        return ",".join(raw)  # a TOML array of strings, as medkit's string[] (auth_clients)
    if isinstance(raw, list):  # a TOML list for a comma-separated setting (topics, categories)
        return ",".join(str(item) for item in raw)
    return str(raw)


SETTINGS: tuple[Setting, ...] = (
    # --- ROS worker (README's settings table) ---
    Setting("sample_timeout", float, 1.0, "seconds a cold read waits for the first message", 0.1, 30),
    Setting("max_pool_size", int, 256, "LRU cap on pooled topic subscriptions", 1, 4096),
    Setting("max_pool_bytes", int, 256 * 2**20, "bytes of kept messages (raw and JSON) before the "
            "least recently read are dropped", 2**20, 2**36),
    Setting("cold_wait_cap", int, 4, "callers allowed to wait on cold topics at once", 1, 4096, "no cap"),
    Setting("idle_safety_net", float, 900.0, "seconds an unread pooled topic is kept", 1, 604800, "off"),
    Setting("idle_sweep_tick", float, 60.0, "seconds between idle sweeps", 0.05, 3600),
    Setting("max_queue_depth", int, 256, "pending ROS-worker commands before backpressure", 1, 65536),
    Setting("watchdog_threshold", int, 5000, "ms a ROS task may run before the worker is degraded", 50, 600000),
    Setting("graph_poll_tick", int, 100, "ms between checks of the ROS graph", 10, 10000),
    Setting("max_publishers", int, 64, "LRU cap on pooled publishers (PUT)", 1, 1024),
    Setting("publish_match_wait", float, 1.0, "seconds a new publisher waits for the topic's "
            "subscribers to match before it publishes", 0, 30),
    Setting("max_subscriptions", int, 1000, "cyclic subscriptions (SSE streams' sources) held at once",
            1, 100000),
    Setting("max_subscriptions_per_client", int, 100, "cyclic subscriptions one client address may hold "
            "at once", 1, 100000),
    Setting("max_stream_duration", int, 3600, "longest duration in seconds a cyclic subscription may ask",
            1, 86400),
    Setting("stream_send_timeout", float, 30.0, "seconds an SSE client may take to take one frame before "
            "it is disconnected", 1, 600),
    Setting("gateway_name", str, "sovd_gateway", "ROS node name prefix; the worker's node is <name>_sub"),
    # --- HTTP side ---
    Setting("bind", str, "127.0.0.1:8080", "HOST:PORT the HTTP server listens on"),
    Setting("workers", int, 2, "gunicorn worker processes", 1, 64),
    Setting("worker_connections", int, 1000,
            "connections one HTTP worker holds at once (idle, reading, in a request or streaming)", 1, 100000),
    Setting("allow_publish", bool, False, "allow PUT .../data/... to publish to ROS topics"),
    Setting("api_token", str, "", "legacy bearer token: an admin credential; with auth_enabled off, writes "
            "need it (empty: none)", secret=True),
    Setting("max_body_bytes", int, 1048576, "largest accepted request body in bytes", 1024, 67108864),
    Setting("ipc_timeout", float, 2.0, "seconds an HTTP worker waits for a non-sample ROS-worker reply", 0.1, 60),
    Setting("header_timeout", float, 15.0, "seconds a client may take to send a request's head", 1, 300),
    Setting("body_timeout", float, 30.0, "seconds a client may take to send a request's body (408 past it)",
            1, 600),
    Setting("forwarded_allow_ips", str, "127.0.0.1,::1", "proxies trusted for X-Forwarded-* headers"),
    # --- operating it in a fleet (README "Metrics, CORS, rate limits, request ids, access log") ---
    Setting("cors_origins", str, "", "browser origins allowed to call the API: a comma-separated list "
            "of exact origins (https://ui.example:8443), or * for any (empty: CORS off)"),
    Setting("rate_limit", str, "", "token bucket per client address: RATE/BURST in requests per second "
            "and requests at once, e.g. 50/100 (empty: off)"),
    Setting("rate_limit_global", str, "", "token bucket over all clients together: RATE/BURST "
            "(empty: off)"),
    Setting("access_log", bool, False, "one line per request on stdout (the journal), at most "
            f"{ACCESS_LOG_RATE:g} lines/s in all"),
    # --- service ---
    Setting("runtime_dir", str, "", "directory for the IPC socket and lock (default: see README)"),
    Setting("log_level", str, "info", "log level", choices=("debug", "info", "warning", "error")),
    Setting("watchdog_grace", float, 10.0, "seconds a hung ROS worker is tolerated before it is killed", 0.5, 600),
    Setting("restart_limit", int, 5, "ROS worker restarts allowed within restart_window", 1, 1000),
    Setting("restart_window", float, 60.0, "seconds over which restarts are counted", 1, 86400),
    Setting("shutdown_grace", float, 5.0, "seconds in-flight HTTP requests get at shutdown", 0.5, 120),
    Setting("debug_commands", bool, False, "enable test-only IPC commands (never in production)"),
    # --- operations (README "Operations: services and actions") ---
    Setting("allow_operations", bool, False, "allow POST/PUT/DELETE on .../operations/.../executions "
            "(calling ROS services, sending and cancelling action goals)"),
    Setting("service_call_timeout", float, 10.0, "seconds a service call or an action's goal or cancel "
            "request waits for the server's answer (504 past it)", 1, 3600),
    Setting("max_operation_clients", int, 64, "LRU cap on pooled service clients, and on pooled action "
            "clients", 1, 1024),
    Setting("max_goals_per_action", int, 100, "goals kept per action (the oldest finished is dropped first)",
            1, 10000),
    Setting("goal_retention", float, 600.0, "seconds a finished goal stays readable", 1, 604800),
    # --- configurations: ROS 2 parameters of the nodes (README "Configurations: ROS 2 parameters") ---
    Setting("allow_configurations", bool, False, "allow PUT and DELETE .../configurations to change ROS 2 "
            "parameters"),
    Setting("parameter_service_timeout", float, 2.0, "seconds a node's parameter services get to answer one "
            "request (503 past it)", 0.1, 30),
    Setting("parameter_negative_cache_s", float, 10.0, "seconds a node whose parameter services did not answer "
            "is answered 503 at once", 1, 3600, "off"),
    Setting("max_parameter_clients", int, 64, "LRU cap on nodes with pooled parameter clients", 1, 4096),
    Setting("parameter_client_idle_s", float, 300.0, "seconds a node's unused parameter clients are kept",
            1, 86400),
    # --- faults: /diagnostics as SOVD faults (rosworker/faults/manager.py, README "Faults") ---
    Setting("state_dir", str, "", "directory of the store faults.db: faults and triggers (default: "
            "$STATE_DIRECTORY, else $XDG_STATE_HOME/sovd-gateway, else ~/.local/state/sovd-gateway)"),
    Setting("fault_confirm_count", int, 3, "failing reports that confirm a fault", 1, 10000),
    Setting("fault_confirm_s", float, 1.0, "seconds of failing reports that confirm a fault", 0.01, 86400),
    Setting("fault_heal_count", int, 3, "passing reports that heal a fault", 1, 10000),
    Setting("fault_stale_s", float, 10.0, "seconds without a report before a status is STALE (CRITICAL)",
            0.1, 86400, "off"),
    Setting("max_faults", int, 1000, "faults kept; the oldest healed or cleared go first", 1, 100000),
    Setting("fault_codes", str, "", "fault codes for status names: 'name=CODE;other name=CODE2'"),
    Setting("fault_snapshot_topics", str, "", "topics captured at confirmation: 'CODE_PATTERN=/t1,/t2;...'"),
    Setting("allow_fault_clear", bool, False, "allow DELETE .../faults (clearing faults)"),
    Setting("max_fault_streams", int, 16, "open GET /faults/stream streams per HTTP worker", 1, 1000),
    # --- logs: /rosout's ring buffers (issue 22; README "Logs") ---
    Setting("log_buffer_size", int, 200, "/rosout lines kept per node (the oldest go first)", 1, 100000),
    Setting("log_max_bytes", int, 64 * 2**20, "bytes of /rosout lines kept in all (the oldest go first)",
            2**16, 2**34),
    Setting("log_max_nodes", int, 2000, "nodes whose /rosout lines are kept (a new node's past it are "
            "dropped and counted)", 1, 100000),
    # --- triggers (README "Triggers") ---
    Setting("max_triggers", int, 1000, "triggers held at once", 1, 100000),
    Setting("max_triggers_per_client", int, 100, "triggers one client address may hold at once", 1, 100000),
    Setting("max_trigger_bytes", int, 16 * 2**20, "bytes of the records of all triggers held at once "
            "(conditions, targets, paths), in memory and in the store", 2**16, 2**30),
    # --- who is acting (issue 31): identities and roles (app/auth/), locks (app/locks/, rosworker/locks/),
    # the audit trail (app/audit/), TLS (app/gunicorn_conf.py); medkit's keys flattened ---
    Setting("auth_enabled", bool, False, "OAuth2 client credentials and JWTs with medkit's four roles"),
    Setting("auth_clients", str, "", "the clients: 'id:secret:role,...' (role: viewer, operator, configurator "
            "or admin)", secret=True),
    Setting("jwt_secret", str, "", "HS256: the signing secret (at least 32 characters); RS256: the private "
            "key's PEM file", secret=True),
    Setting("jwt_public_key", str, "", "RS256: the public key's PEM file"),
    Setting("jwt_algorithm", str, "HS256", "how tokens are signed", choices=("HS256", "RS256")),
    Setting("auth_issuer", str, "sovd_gateway", "the iss claim of the tokens (checked on every token)"),
    Setting("require_auth_for", str, "write", "with auth on: which requests need a token (all: every one "
            "but /api/v1/auth/**)", choices=("none", "write", "all")),
    Setting("token_expiry_seconds", int, 3600, "lifetime of an access token", 1, 31536000),
    Setting("refresh_token_expiry_seconds", int, 86400, "lifetime of a refresh token", 1, 31536000),
    Setting("auth_failure_limit", str, "1/30", "failed authorizations one client address may make: "
            "RATE/BURST (failures per second, failures at once); past it 429 (empty: no limit)"),
    Setting("locking_enabled", bool, True, "SOVD locks on components and apps (a lock blocks everyone "
            "else's writes in its scopes)"),
    Setting("locking_default_max_expiration", int, 3600, "longest lock_expiration a client may ask, in "
            "seconds", 1, 604800),
    Setting("locking_cleanup_interval", int, 30, "seconds between sweeps of expired locks", 1, 3600),
    Setting("max_locks", int, 1000, "locks held at once", 1, 100000),
    Setting("audit_max_records", int, 100000, "audit records kept (the oldest go first)", 100, 10000000, "off"),
    Setting("audit_max_age_days", int, 90, "days an audit record is kept", 1, 3650),
    Setting("tls_cert", str, "", "the server certificate's PEM file: TLS 1.2 or newer on the bind address "
            "(empty: plain HTTP)"),
    Setting("tls_key", str, "", "the private key's PEM file of tls_cert"),
    Setting("tls_min_version", str, "1.2", "the oldest TLS version a client may speak",
            choices=("1.2", "1.3")),
    # --- the fleet over Zenoh (issue 34; docs/fleet.md, supervisor/fleet/, app/fleet/) ---
    Setting("fleet_link", bool, False, "join the fleet: a fleet-link process answers the fleet's Zenoh "
            "queries from this gateway's API and publishes its fault and trigger events"),
    Setting("fleet_aggregate", bool, False, "run as the fleet gateway: no ROS worker; the robots' trees "
            "merged, their requests forwarded and fanned out (medkit's aggregation contract)"),
    Setting("fleet_connect", str, "", "Zenoh router endpoints to connect to, comma-separated "
            "(e.g. tls/fleet.example.com:7447)"),
    Setting("fleet_id", str, "", "this robot's name in the fleet (default: its host name made an entity id)"),
    Setting("fleet_zenoh_config", str, "", "Zenoh configuration file (JSON5: TLS certificates, access "
            "control ...); mode and fleet_connect are applied on top of it"),
    Setting("fleet_allow_writes", bool, False, "let writes (PUT, POST, DELETE) pass through the fleet "
            "(each side checks its own switch; the caller's token goes along)"),
    Setting("fleet_timeout", float, 2.0, "seconds one robot gets to answer a fleet request "
            "(medkit's aggregation.timeout_ms)", 0.1, 60),
    Setting("fleet_max_robots", int, 1000, "robots the fleet gateway keeps (trees, link state, metric "
            "labels); a robot past it is refused and counted", 1, 100000),
    Setting("fleet_tree_refresh", float, 60.0, "seconds between two reads of a robot's entity tree when it "
            "announced no change (it announces changes itself)", 1, 86400),
    Setting("fleet_forget_after", float, 86400.0, "seconds a disconnected robot's tree stays in the fleet "
            "view, marked unavailable", 1, 31536000, "never"),
    # --- bulk data (issue 32): fault recordings (rosworker/bulk_data/) and medkit's bulk-data routes
    #     (app/bulk_data/); medkit's snapshots.rosbag.* and bulk_data.* flattened ---
    Setting("fault_rosbag_enabled", bool, False, "record fault_rosbag_topics in a ring buffer and write what "
            "led up to each confirmed fault as an MCAP file (medkit's snapshots.rosbag.enabled)"),
    Setting("fault_rosbag_topics", str, "", "topics recorded, comma-separated (or a TOML list); none: "
            "nothing is subscribed"),
    Setting("fault_rosbag_duration_s", float, 5.0, "seconds of messages kept before a fault", 0.1, 3600),
    Setting("fault_rosbag_duration_after_s", float, 1.0, "seconds recorded after a fault is confirmed",
            0, 600),
    Setting("fault_rosbag_format", str, "mcap", "recording format: mcap (sqlite3, rosbag2's other format, is "
            "not written by this gateway)"),
    Setting("fault_rosbag_storage_path", str, "", "directory of the recordings (default: <state_dir>/rosbags)"),
    Setting("fault_rosbag_max_buffer_mb", int, 256, "MB of messages the ring buffer (and an open recording) "
            "holds; past it the oldest are dropped and counted", 1, 65536),
    Setting("fault_rosbag_max_total_mb", int, 500, "MB of recordings on disk; the oldest are deleted first",
            1, 10_000_000),
    Setting("fault_rosbag_max_bags_per_fault", int, 1, "recordings kept per fault code (the newest)",
            1, 10000, "no cap"),
    Setting("bulk_data_storage_dir", str, "", "directory of the uploaded bulk-data files (default: "
            "<state_dir>/bulk_data)"),
    Setting("bulk_data_max_upload_size", int, 100 * 2**20, "largest bulk-data upload in bytes (413 past it)",
            1, 2**40),
    Setting("bulk_data_max_total_mb", int, 1024, "MB of uploaded bulk-data files in all (507 past it)",
            1, 10_000_000),
    Setting("bulk_data_categories", str, "", "bulk-data categories of uploaded files, comma-separated (e.g. "
            "calibration,firmware); rosbags is always there"),
    Setting("allow_bulk_data", bool, False, "allow POST and DELETE on .../bulk-data (uploading and deleting "
            "files of the bulk_data_categories)"),
)

BY_NAME = {s.name: s for s in SETTINGS}
# Settings that no longer exist: still accepted from every source, and ignored with a note
# (``Config.ignored``, logged by ``sovd-gateway`` at start-up), so an old config does not stop a robot.
RETIRED = {
    "threads": "the HTTP workers run an event loop, not threads; "
               "worker_connections bounds what one worker holds",
    "trigger_store": "the triggers are kept in the fault store (faults.db in state_dir); a triggers.json "
                     "of an older gateway is imported once",
}
_RATE = re.compile(r"^\s*([0-9]+(?:\.[0-9]+)?)\s*(?:/\s*([0-9]+)\s*)?$")
_ORIGIN = re.compile(r"^https?://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9-]+(\.[A-Za-z0-9-]+)*)(:[0-9]{1,5})?$")
_NODE_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,200}$")
_BIND = re.compile(r"^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})$")


class Config(dict):
    """Resolved settings; attribute access for convenience (``cfg.sample_timeout``).

    ``ignored`` lists what was given for a retired setting, one sentence each.
    """

    ignored: tuple[str, ...] = ()

    def __getattr__(self, name: str) -> Any:
        try:
            return self[name]
        except KeyError:
            raise AttributeError(name) from None

    def to_env(self) -> dict[str, str]:
        """The settings as ``SOVD_*`` variables, for a child process."""
        out = {}
        for s in SETTINGS:
            value = self[s.name]
            out[s.env] = ("1" if value else "0") if s.kind is bool else str(value)
        return out


def add_arguments(parser: argparse.ArgumentParser, names: tuple[str, ...] | None = None) -> None:
    """Add ``--config`` and one flag per setting (all, or those named)."""
    parser.add_argument("--config", metavar="FILE", help="TOML config file (settings as top-level keys)")
    for s in SETTINGS:
        if names is not None and s.name not in names:
            continue
        if s.secret:
            # Taken only to refuse it with a clear message in load(): a flag shows the secret in ps.
            parser.add_argument(s.flag, dest=s.name, default=None, help=argparse.SUPPRESS)
        elif s.kind is bool and s.default:  # on by default: --no-<name> turns it off
            parser.add_argument(s.flag, dest=s.name, action=argparse.BooleanOptionalAction, default=None,
                                help=s.help + " (default on)")
        elif s.kind is bool:
            parser.add_argument(s.flag, dest=s.name, action="store_const", const=True, default=None, help=s.help)
        else:
            rng = s.range_text()
            parser.add_argument(
                s.flag, dest=s.name, default=None, metavar=s.kind.__name__.upper(),
                help=f"{s.help} (default {s.default!r}{'; ' + rng if rng else ''})",
            )
    if names is None:
        for name in RETIRED:
            parser.add_argument("--" + name.replace("_", "-"), dest=name, default=None, help=argparse.SUPPRESS)


def load(args: argparse.Namespace | None = None, environ: dict[str, str] | None = None) -> Config:
    """Resolve every setting: default < config file < environment < flags."""
    environ = os.environ if environ is None else environ
    flags = vars(args) if args is not None else {}
    values: dict[str, Any] = {s.name: s.default for s in SETTINGS}
    sources: dict[str, str] = {}  # where a value came from, for the messages of the checks below
    ignored: list[str] = []

    def retired(name: str, source: str) -> None:
        ignored.append(f"{name} (from {source}) is no longer a setting and is ignored: {RETIRED[name]}")

    path = flags.get("config") or environ.get(ENV_PREFIX + "CONFIG")
    if path:
        try:
            with open(path, "rb") as fh:
                data = tomllib.load(fh)
        except OSError as exc:
            raise ConfigError(f"config file {path}: {exc.strerror}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"config file {path}: not valid TOML ({exc})") from None
        data = data.get("sovd_gateway", data)
        for key, raw in data.items():
            setting = BY_NAME.get(key)
            if key in RETIRED:
                retired(key, f"config file {path}")
                continue
            if setting is None:
                raise ConfigError(f"config file {path}: unknown setting {key!r}")
            values[key] = setting.parse(raw, f"config file {path}")
            sources[key] = f"config file {path}"

    for s in SETTINGS:
        if s.env in environ:
            values[s.name] = s.parse(environ[s.env], f"environment {s.env}")
            sources[s.name] = f"environment {s.env}"
        if flags.get(s.name) is not None:
            if s.secret:
                raise ConfigError(f"{s.name}: a secret is never given as a flag ({s.flag}): every user of "
                                  "the machine sees a command line. Put it in the config file (--config) or "
                                  f"the environment ({s.env}, e.g. in the service's EnvironmentFile)")
            values[s.name] = s.parse(flags[s.name], f"flag {s.flag}")
            sources[s.name] = f"flag {s.flag}"
    for name in RETIRED:
        env = ENV_PREFIX + name.upper()
        if env in environ:
            retired(name, f"environment {env}")
        if flags.get(name) is not None:
            retired(name, "flag --" + name.replace("_", "-"))

    if not _NODE_NAME.match(values["gateway_name"]):
        raise ConfigError(
            f"gateway_name: {values['gateway_name']!r} is not a valid ROS node name "
            "(a letter, then letters, digits or _)"
        )
    m = _BIND.match(values["bind"])
    if not m or not (0 < int(m.group(2)) < 65536):
        raise ConfigError(f"bind: {values['bind']!r} is not HOST:PORT with a port of 1–65535")
    if not values["runtime_dir"]:
        values["runtime_dir"] = default_runtime_dir(environ)
    if values["api_token"] and len(values["api_token"]) < 16:
        raise ConfigError("api_token: use at least 16 characters")
    def named(name: str) -> str:
        return f"{name} (from {sources[name]})" if name in sources else name

    check_fleet(values)
    for name in ("rate_limit", "rate_limit_global", "auth_failure_limit"):
        parse_rate(values[name], named(name))
    _check_identity(values, named)
    parse_origins(values["cors_origins"], named("cors_origins"))
    check_bulk_data(values, named)
    cfg = Config(values)
    cfg.ignored = tuple(ignored)
    return cfg


ROLES = ("viewer", "operator", "configurator", "admin")  # medkit's four, least to most (app/auth/roles.py)
_CLIENT_ID = re.compile(r"^[A-Za-z0-9_.@-]{1,128}$")


@dataclass(frozen=True)
class Client:
    """One client of ``auth_clients`` (``id:secret:role``)."""

    client_id: str
    secret: str
    role: str

    def __repr__(self) -> str:  # never the secret, whoever prints one
        return f"Client({self.client_id!r}, role={self.role!r})"


def parse_clients(text: str, name: str = "auth_clients") -> tuple[Client, ...]:
    """``"admin:s3cret:admin,viewer:x:viewer"`` → the clients; the secret is what stands between the
    first and the last ``:`` (it may hold ``:`` itself).  An error never quotes a secret."""
    clients: list[Client] = []
    for number, item in enumerate((part.strip() for part in text.split(",")), 1):
        if not item:
            continue
        client_id, sep, rest = item.partition(":")
        secret, sep2, role = rest.rpartition(":")
        if not sep or not sep2:
            raise ConfigError(f"{name}: entry {number} is not id:secret:role")
        if not _CLIENT_ID.match(client_id):
            raise ConfigError(f"{name}: entry {number}: the client id must be 1–128 letters, digits or _ . @ -")
        if not secret:
            raise ConfigError(f"{name}: client {client_id!r} has an empty secret")
        if role.strip().lower() not in ROLES:
            raise ConfigError(f"{name}: client {client_id!r}: the role must be one of {', '.join(ROLES)}")
        if any(c.client_id == client_id for c in clients):
            raise ConfigError(f"{name}: client {client_id!r} is given twice")
        clients.append(Client(client_id, secret, role.strip().lower()))
    return tuple(clients)


def _check_identity(values: dict[str, Any], named: Any) -> None:
    """The auth and TLS settings, as medkit's AuthConfigBuilder checks them; never quotes a secret."""
    parse_clients(values["auth_clients"], named("auth_clients"))
    if values["auth_enabled"]:
        if not values["auth_clients"].strip() and not values["api_token"]:
            raise ConfigError("auth_enabled: give the clients in auth_clients (config file or "
                              "SOVD_AUTH_CLIENTS): id:secret:role,...")
        if values["jwt_algorithm"] == "HS256" and len(values["jwt_secret"]) < 32:
            raise ConfigError("jwt_secret: HS256 needs a secret of at least 32 characters (config file or "
                              "SOVD_JWT_SECRET; e.g. openssl rand -base64 32)")
        if values["jwt_algorithm"] == "RS256":
            for key in ("jwt_secret", "jwt_public_key"):
                path = values[key]
                if not path or not os.path.isfile(path) or not os.access(path, os.R_OK):
                    raise ConfigError(f"{key}: RS256 needs a readable PEM file here"
                                      + (" (the private key)" if key == "jwt_secret" else " (the public key)"))
        if values["refresh_token_expiry_seconds"] < values["token_expiry_seconds"]:
            raise ConfigError("refresh_token_expiry_seconds: must be at least token_expiry_seconds")
    if bool(values["tls_cert"]) != bool(values["tls_key"]):
        raise ConfigError("tls_cert, tls_key: give both (the certificate and its private key), or neither")
    for key in ("tls_cert", "tls_key"):
        path = values[key]
        if path and (not os.path.isfile(path) or not os.access(path, os.R_OK)):
            raise ConfigError(f"{named(key)}: {path!r} is not a readable file")


# ---- bulk data (issue 32) ---------------------------------------------------------------------------
ROSBAGS = "rosbags"  # the recordings' category: always there, read-only
_CATEGORY = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")
_TOPIC_NAME = re.compile(r"^/[A-Za-z0-9_~{}/]*$")


def names(text: str) -> list[str]:
    """A comma-separated setting's items (topics, categories), stripped, empty ones left out, each once."""
    return list(dict.fromkeys(item.strip() for item in text.split(",") if item.strip()))


def check_bulk_data(values: dict[str, Any], named=lambda name: name) -> None:
    if values["fault_rosbag_format"] != "mcap":
        fmt = values["fault_rosbag_format"]
        raise ConfigError(f"{named('fault_rosbag_format')}: {fmt!r} is not written by this gateway: "
                          + ("sqlite3 (rosbag2's db3) needs rosbag2's C++ storage plugin; " if fmt == "sqlite3" else "")
                          + "use mcap, which ros2 bag, Foxglove and medkit's clients read")
    for topic in names(values["fault_rosbag_topics"]):
        if not _TOPIC_NAME.match(topic) or "//" in topic or (len(topic) > 1 and topic.endswith("/")):
            raise ConfigError(f"{named('fault_rosbag_topics')}: {topic!r} is not a topic name "
                              "(absolute: /robot/odom)")
    for category in names(values["bulk_data_categories"]):
        if category == ROSBAGS or not _CATEGORY.match(category):
            raise ConfigError(f"{named('bulk_data_categories')}: {category!r} cannot be a category (1-64 "
                              "letters, digits, _ and -, starting with a letter or digit; not rosbags, "
                              "which is the fault recordings')")


def rosbag_dir(cfg: dict[str, Any], environ=os.environ) -> str:
    """Where the fault recordings are: ``fault_rosbag_storage_path``, else ``<state_dir>/rosbags``."""
    return cfg["fault_rosbag_storage_path"] or os.path.join(cfg["state_dir"] or default_state_dir(environ),
                                                            ROSBAGS)


def bulk_data_dir(cfg: dict[str, Any], environ=os.environ) -> str:
    """Where uploaded bulk-data files are: ``bulk_data_storage_dir``, else ``<state_dir>/bulk_data``."""
    return cfg["bulk_data_storage_dir"] or os.path.join(cfg["state_dir"] or default_state_dir(environ),
                                                        "bulk_data")


# ---- the fleet (issue 34) -------------------------------------------------------------------------
FLEET_ID_MAX = 64
# An entity id's characters, no "__" (medkit's rename separator) and no leading or trailing "_".
_FLEET_ID = re.compile(r"^[A-Za-z0-9-]+(?:_[A-Za-z0-9-]+)*$")


def default_fleet_id(hostname: str) -> str:
    """The host name as a fleet id: lower case, ``[a-z0-9-]`` and single ``_`` only, at most 64."""
    text = re.sub(r"[^a-z0-9-]+", "_", hostname.lower()).strip("_")[:FLEET_ID_MAX].strip("_")
    return text or "robot"


def check_fleet(values: dict[str, Any]) -> None:
    """The fleet settings together: one role, somewhere to connect, an identity to check, a valid id."""
    if not (values["fleet_link"] or values["fleet_aggregate"]):
        return
    if values["fleet_link"] and values["fleet_aggregate"]:
        raise ConfigError("fleet_link and fleet_aggregate: a fleet gateway runs no ROS worker, so it has "
                          "nothing of its own to answer; turn one of them off")
    role = "fleet_link" if values["fleet_link"] else "fleet_aggregate"
    if not values["fleet_connect"].strip() and not values["fleet_zenoh_config"]:
        raise ConfigError(f"{role}: give fleet_connect (the Zenoh router, e.g. tcp/10.0.0.1:7447) or a "
                          "fleet_zenoh_config that names one")
    if not values["api_token"]:
        raise ConfigError(f"{role}: set api_token: nothing is answered through the fleet without a valid "
                          "identity (the caller's bearer token, checked by the robot's own gateway)")
    if values["fleet_zenoh_config"] and not os.path.isfile(values["fleet_zenoh_config"]):
        raise ConfigError(f"fleet_zenoh_config: {values['fleet_zenoh_config']!r} is not a file")
    if not values["fleet_id"]:
        import socket

        values["fleet_id"] = default_fleet_id(socket.gethostname())
    if len(values["fleet_id"]) > FLEET_ID_MAX or not _FLEET_ID.match(values["fleet_id"]):
        raise ConfigError(f"fleet_id: {values['fleet_id']!r} is not a fleet id: 1–{FLEET_ID_MAX} letters, "
                          "digits, - and single _ (not first or last: __ separates a robot's name from a "
                          "renamed app's id)")


@dataclass(frozen=True)
class Rate:
    """A token bucket: ``rate`` tokens per second, at most ``burst`` at once.

    The one refill rule of the gateway's buckets: the rate limiter's (``app/ratelimit.py``)
    and the access log's (``app/core/accesslog.py``).
    """

    rate: float
    burst: float  # an int when parsed from a setting (it is the X-RateLimit-Limit header)

    def refill(self, tokens: float, elapsed: float) -> float:
        """The tokens of a bucket that held ``tokens`` ``elapsed`` seconds ago (never above the burst)."""
        return min(float(self.burst), tokens + max(0.0, elapsed) * self.rate)


def parse_rate(text: str, name: str = "rate_limit") -> Rate | None:
    """``"50/100"`` → ``Rate(50.0, 100)``; ``"50"`` → ``Rate(50.0, 50)``; empty → None (off)."""
    if not text.strip():
        return None
    m = _RATE.match(text)
    if not m:
        raise ConfigError(f"{name}: {text!r} is not RATE/BURST (requests per second and requests at "
                          "once, e.g. 50/100), or empty for off")
    rate = float(m.group(1))
    burst = int(m.group(2)) if m.group(2) is not None else max(1, math.ceil(rate))
    if not 0 < rate <= RATE_MAX:
        raise ConfigError(f"{name}: rate {m.group(1)} is out of range (allowed: above 0, at most "
                          f"{RATE_MAX:g} requests per second)")
    if not 1 <= burst <= BURST_MAX:
        raise ConfigError(f"{name}: burst {burst} is out of range (allowed: 1–{BURST_MAX})")
    return Rate(rate, burst)


def parse_origins(text: str, name: str = "cors_origins") -> tuple[str, ...] | str | None:
    """``cors_origins``: None (off), ``"*"`` (any origin), or the exact origins allowed."""
    items = [item.strip() for item in text.split(",") if item.strip()]
    if not items:
        return None
    if "*" in items:
        if len(items) > 1:
            raise ConfigError(f"{name}: * allows every origin; give it alone, or list exact origins")
        return "*"
    origins = []
    for item in items:
        m = _ORIGIN.match(item)
        if not m or (m.group(3) and not 0 < int(m.group(3)[1:]) < 65536):
            raise ConfigError(f"{name}: {item!r} is not an origin: scheme://host[:port] with http or "
                              "https, no path and no trailing slash (e.g. https://dashboard.example:8443)")
        host = m.group(1)
        if host.startswith("["):
            # An IPv6 literal, written as a browser writes it in Origin (lower case, zeros
            # compressed): http://[FD00:0::10]:8443 is the origin http://[fd00::10]:8443.
            try:
                address = ipaddress.IPv6Address(host[1:-1])
            except ValueError:
                raise ConfigError(f"{name}: {item!r}: {host} is not an IPv6 address") from None
            item = item.replace(host, f"[{address.compressed}]", 1)
        origins.append(item)
    return tuple(dict.fromkeys(origins))


def default_runtime_dir(environ: dict[str, str] | os._Environ) -> str:
    """``$RUNTIME_DIRECTORY`` (systemd), else a private dir under ``$XDG_RUNTIME_DIR`` or the temp dir."""
    if environ.get("RUNTIME_DIRECTORY"):
        return environ["RUNTIME_DIRECTORY"].split(":")[0]
    base = environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir()
    return os.path.join(base, f"sovd-gateway-{os.getuid()}")


def default_state_dir(environ: dict[str, str] | os._Environ) -> str:
    """The fault store's directory (faults): ``$STATE_DIRECTORY`` (systemd), else XDG's state home."""
    if environ.get("STATE_DIRECTORY"):
        return environ["STATE_DIRECTORY"].split(":")[0]
    base = environ.get("XDG_STATE_HOME") or os.path.join(os.path.expanduser("~"), ".local", "state")
    return os.path.join(base, "sovd-gateway")


def ensure_runtime_dir(path: str) -> str:
    """Create the runtime directory 0700 and refuse one that others can enter."""
    os.makedirs(path, mode=0o700, exist_ok=True)
    st = os.stat(path)
    if st.st_uid != os.getuid():
        raise ConfigError(f"runtime_dir {path}: owned by uid {st.st_uid}, not by this user ({os.getuid()})")
    if st.st_mode & 0o077:
        os.chmod(path, 0o700)
    return path


def restart_attempt(environ: dict | os._Environ) -> int:
    """Which restart a ROS worker is (0: the first boot), as the supervisor said (``RESTART_ENV``)."""
    try:
        return max(0, int(environ.get(RESTART_ENV, "0")))
    except ValueError:
        return 0
