"""Who may do what: medkit's four roles and their permission table, as data, in this one module.

The table is medkit's (``src/ros2_medkit_gateway/src/core/auth/auth_config.cpp``,
``AuthConfig::get_role_permissions``), entry for entry: ``METHOD:/path`` with ``*`` for one path
segment and ``**`` for any number.  A role may send a request when one of its entries matches the
method and the request's path (``app/core/target.py`` makes one segment of a data id or an operation
id that holds slashes).  ``HEAD`` is checked as ``GET``.  What the table does not list is refused
to every role but admin, as in medkit: triggers (read and write), the per-entity ``docs``, the
audit trail.  medkit's documentation says otherwise in two places; this table, like medkit's
code, lets operators and configurators clear faults, and lets only admin touch triggers.

:data:`EXTRA` adds what medkit has no route for: ``GET /metrics`` (Prometheus), for every role.

:data:`ACTIONS` names what an operator or the dashboard asks about ("may this role publish?"),
each by one request; :func:`summary` answers them for a role (``GET /api/v1/auth/x-medkit-whoami``,
the dashboard) and :func:`markdown` makes the README's table from them:
``python -m app.auth.roles --write`` rewrites it, ``tests/app/auth/test_app_auth_roles.py`` fails when the
committed README differs.
"""

from __future__ import annotations

import functools
import re
import sys
from pathlib import Path

from common.settings import ROLES

# ---- medkit's table (auth_config.cpp) ------------------------------------------------------------
VIEWER = (
    "GET:/api/v1/health", "GET:/api/v1/", "GET:/api/v1/version-info", "GET:/api/v1/areas",
    "GET:/api/v1/areas/*", "GET:/api/v1/components", "GET:/api/v1/components/*", "GET:/api/v1/apps",
    "GET:/api/v1/apps/*", "GET:/api/v1/functions", "GET:/api/v1/functions/*",
    "GET:/api/v1/areas/*/components", "GET:/api/v1/areas/*/subareas", "GET:/api/v1/areas/*/contains",
    "GET:/api/v1/components/*/subcomponents", "GET:/api/v1/components/*/hosts",
    "GET:/api/v1/components/*/depends-on", "GET:/api/v1/apps/*/depends-on",
    "GET:/api/v1/apps/*/is-located-on", "GET:/api/v1/apps/*/belongs-to", "GET:/api/v1/functions/*/hosts",
    "GET:/api/v1/components/*/data", "GET:/api/v1/components/*/data/*", "GET:/api/v1/apps/*/data",
    "GET:/api/v1/apps/*/data/*", "GET:/api/v1/areas/*/data", "GET:/api/v1/areas/*/data/*",
    "GET:/api/v1/functions/*/data", "GET:/api/v1/functions/*/data/*",
    "GET:/api/v1/components/*/data-categories", "GET:/api/v1/components/*/data-groups",
    "GET:/api/v1/apps/*/data-categories", "GET:/api/v1/apps/*/data-groups",
    "GET:/api/v1/areas/*/data-categories", "GET:/api/v1/areas/*/data-groups",
    "GET:/api/v1/functions/*/data-categories", "GET:/api/v1/functions/*/data-groups",
    "GET:/api/v1/components/*/operations", "GET:/api/v1/components/*/operations/*",
    "GET:/api/v1/components/*/operations/*/executions",
    "GET:/api/v1/components/*/operations/*/executions/*", "GET:/api/v1/apps/*/operations",
    "GET:/api/v1/apps/*/operations/*", "GET:/api/v1/apps/*/operations/*/executions",
    "GET:/api/v1/apps/*/operations/*/executions/*", "GET:/api/v1/areas/*/operations",
    "GET:/api/v1/areas/*/operations/*", "GET:/api/v1/areas/*/operations/*/executions",
    "GET:/api/v1/areas/*/operations/*/executions/*", "GET:/api/v1/functions/*/operations",
    "GET:/api/v1/functions/*/operations/*", "GET:/api/v1/functions/*/operations/*/executions",
    "GET:/api/v1/functions/*/operations/*/executions/*", "GET:/api/v1/components/*/configurations",
    "GET:/api/v1/components/*/configurations/*", "GET:/api/v1/apps/*/configurations",
    "GET:/api/v1/apps/*/configurations/*", "GET:/api/v1/areas/*/configurations",
    "GET:/api/v1/areas/*/configurations/*", "GET:/api/v1/functions/*/configurations",
    "GET:/api/v1/functions/*/configurations/*", "GET:/api/v1/components/*/faults",
    "GET:/api/v1/components/*/faults/*", "GET:/api/v1/apps/*/faults", "GET:/api/v1/apps/*/faults/*",
    "GET:/api/v1/areas/*/faults", "GET:/api/v1/areas/*/faults/*", "GET:/api/v1/functions/*/faults",
    "GET:/api/v1/functions/*/faults/*", "GET:/api/v1/faults", "GET:/api/v1/faults/stream",
    "GET:/api/v1/components/*/logs", "GET:/api/v1/components/*/logs/configuration",
    "GET:/api/v1/apps/*/logs", "GET:/api/v1/apps/*/logs/configuration", "GET:/api/v1/areas/*/logs",
    "GET:/api/v1/areas/*/logs/configuration", "GET:/api/v1/functions/*/logs",
    "GET:/api/v1/functions/*/logs/configuration", "GET:/api/v1/components/*/bulk-data",
    "GET:/api/v1/components/*/bulk-data/*", "GET:/api/v1/components/*/bulk-data/*/*",
    "GET:/api/v1/apps/*/bulk-data", "GET:/api/v1/apps/*/bulk-data/*", "GET:/api/v1/apps/*/bulk-data/*/*",
    "GET:/api/v1/areas/*/bulk-data", "GET:/api/v1/areas/*/bulk-data/*", "GET:/api/v1/areas/*/bulk-data/*/*",
    "GET:/api/v1/functions/*/bulk-data", "GET:/api/v1/functions/*/bulk-data/*",
    "GET:/api/v1/functions/*/bulk-data/*/*", "GET:/api/v1/areas/*/subareas/*/bulk-data",
    "GET:/api/v1/areas/*/subareas/*/bulk-data/*", "GET:/api/v1/areas/*/subareas/*/bulk-data/*/*",
    "GET:/api/v1/components/*/subcomponents/*/bulk-data",
    "GET:/api/v1/components/*/subcomponents/*/bulk-data/*",
    "GET:/api/v1/components/*/subcomponents/*/bulk-data/*/*",
    "GET:/api/v1/components/*/cyclic-subscriptions", "GET:/api/v1/components/*/cyclic-subscriptions/*",
    "GET:/api/v1/components/*/cyclic-subscriptions/*/events", "GET:/api/v1/apps/*/cyclic-subscriptions",
    "GET:/api/v1/apps/*/cyclic-subscriptions/*", "GET:/api/v1/apps/*/cyclic-subscriptions/*/events",
    "GET:/api/v1/functions/*/cyclic-subscriptions", "GET:/api/v1/functions/*/cyclic-subscriptions/*",
    "GET:/api/v1/functions/*/cyclic-subscriptions/*/events", "GET:/api/v1/components/*/locks",
    "GET:/api/v1/components/*/locks/*", "GET:/api/v1/apps/*/locks", "GET:/api/v1/apps/*/locks/*",
    "GET:/api/v1/updates", "GET:/api/v1/updates/*", "GET:/api/v1/updates/*/status",
    "GET:/api/v1/components/*/scripts", "GET:/api/v1/components/*/scripts/*", "GET:/api/v1/apps/*/scripts",
    "GET:/api/v1/apps/*/scripts/*", "GET:/api/v1/components/*/scripts/*/executions/*",
    "GET:/api/v1/apps/*/scripts/*/executions/*", "GET:/api/v1/apps/*/status",
    "GET:/api/v1/components/*/status", "GET:/api/v1/docs",
)
OPERATOR_ADDS = (
    "POST:/api/v1/components/*/operations/*/executions", "POST:/api/v1/apps/*/operations/*/executions",
    "POST:/api/v1/areas/*/operations/*/executions", "POST:/api/v1/functions/*/operations/*/executions",
    "PUT:/api/v1/components/*/operations/*/executions/*", "PUT:/api/v1/apps/*/operations/*/executions/*",
    "PUT:/api/v1/areas/*/operations/*/executions/*", "PUT:/api/v1/functions/*/operations/*/executions/*",
    "DELETE:/api/v1/components/*/operations/*/executions/*",
    "DELETE:/api/v1/apps/*/operations/*/executions/*", "DELETE:/api/v1/areas/*/operations/*/executions/*",
    "DELETE:/api/v1/functions/*/operations/*/executions/*", "DELETE:/api/v1/components/*/faults/*",
    "DELETE:/api/v1/apps/*/faults/*", "DELETE:/api/v1/areas/*/faults/*",
    "DELETE:/api/v1/functions/*/faults/*", "DELETE:/api/v1/components/*/faults",
    "DELETE:/api/v1/apps/*/faults", "DELETE:/api/v1/areas/*/faults", "DELETE:/api/v1/functions/*/faults",
    "DELETE:/api/v1/faults", "PUT:/api/v1/components/*/data/*", "PUT:/api/v1/apps/*/data/*",
    "PUT:/api/v1/areas/*/data/*", "PUT:/api/v1/functions/*/data/*",
    "POST:/api/v1/components/*/cyclic-subscriptions", "POST:/api/v1/apps/*/cyclic-subscriptions",
    "POST:/api/v1/functions/*/cyclic-subscriptions", "PUT:/api/v1/components/*/cyclic-subscriptions/*",
    "PUT:/api/v1/apps/*/cyclic-subscriptions/*", "PUT:/api/v1/functions/*/cyclic-subscriptions/*",
    "DELETE:/api/v1/components/*/cyclic-subscriptions/*", "DELETE:/api/v1/apps/*/cyclic-subscriptions/*",
    "DELETE:/api/v1/functions/*/cyclic-subscriptions/*", "POST:/api/v1/components/*/locks",
    "POST:/api/v1/apps/*/locks", "PUT:/api/v1/components/*/locks/*", "PUT:/api/v1/apps/*/locks/*",
    "DELETE:/api/v1/components/*/locks/*", "DELETE:/api/v1/apps/*/locks/*",
    "POST:/api/v1/components/*/bulk-data/*", "POST:/api/v1/apps/*/bulk-data/*",
    "DELETE:/api/v1/components/*/bulk-data/*/*", "DELETE:/api/v1/apps/*/bulk-data/*/*",
    "POST:/api/v1/components/*/scripts/*/executions", "POST:/api/v1/apps/*/scripts/*/executions",
    "PUT:/api/v1/components/*/scripts/*/executions/*", "PUT:/api/v1/apps/*/scripts/*/executions/*",
    "DELETE:/api/v1/components/*/scripts/*/executions/*", "DELETE:/api/v1/apps/*/scripts/*/executions/*",
    "PUT:/api/v1/apps/*/status/start", "PUT:/api/v1/apps/*/status/restart",
    "PUT:/api/v1/apps/*/status/force-restart", "PUT:/api/v1/components/*/status/start",
    "PUT:/api/v1/components/*/status/restart", "PUT:/api/v1/components/*/status/force-restart",
)
CONFIGURATOR_ADDS = (
    "PUT:/api/v1/apps/*/status/shutdown", "PUT:/api/v1/apps/*/status/force-shutdown",
    "PUT:/api/v1/components/*/status/shutdown", "PUT:/api/v1/components/*/status/force-shutdown",
    "PUT:/api/v1/components/*/configurations/*", "PUT:/api/v1/apps/*/configurations/*",
    "PUT:/api/v1/areas/*/configurations/*", "PUT:/api/v1/functions/*/configurations/*",
    "DELETE:/api/v1/components/*/configurations", "DELETE:/api/v1/components/*/configurations/*",
    "DELETE:/api/v1/apps/*/configurations", "DELETE:/api/v1/apps/*/configurations/*",
    "DELETE:/api/v1/areas/*/configurations", "DELETE:/api/v1/areas/*/configurations/*",
    "DELETE:/api/v1/functions/*/configurations", "DELETE:/api/v1/functions/*/configurations/*",
    "PUT:/api/v1/components/*/logs/configuration", "PUT:/api/v1/apps/*/logs/configuration",
    "PUT:/api/v1/areas/*/logs/configuration", "PUT:/api/v1/functions/*/logs/configuration",
    "POST:/api/v1/components/*/scripts", "POST:/api/v1/apps/*/scripts",
    "DELETE:/api/v1/components/*/scripts/*", "DELETE:/api/v1/apps/*/scripts/*", "POST:/api/v1/updates",
    "PUT:/api/v1/updates/*/prepare", "PUT:/api/v1/updates/*/execute", "PUT:/api/v1/updates/*/automated",
    "DELETE:/api/v1/updates/*",
)
ADMIN = (
    "GET:/api/v1/**", "POST:/api/v1/**", "PUT:/api/v1/**", "DELETE:/api/v1/**",
    "POST:/api/v1/auth/authorize", "POST:/api/v1/auth/token", "POST:/api/v1/auth/revoke",
)

# What each role may do: each role has its own entries and every entry of the roles before it.
TABLE: dict[str, tuple[str, ...]] = {
    "viewer": VIEWER,
    "operator": VIEWER + OPERATOR_ADDS,
    "configurator": VIEWER + OPERATOR_ADDS + CONFIGURATOR_ADDS,
    "admin": ADMIN,
}
# ---- this gateway's routes that medkit does not have ------------------------------------------------
EXTRA = ("GET:/metrics",)


@functools.cache
def _matcher(role: str, method: str) -> re.Pattern[str] | None:
    """One regular expression for every entry of ``role`` with ``method`` (medkit's wildcard rules)."""
    paths = [entry.partition(":")[2] for entry in TABLE[role] + EXTRA if entry.partition(":")[0] == method]
    if not paths:
        return None
    alternatives = ("".join(".*" if part == "**" else "[^/]+" if part == "*" else re.escape(part)
                            for part in re.split(r"(\*\*|\*)", path)) for path in paths)
    return re.compile("(?:" + "|".join(alternatives) + ")")


@functools.lru_cache(maxsize=8192)
def allowed(role: str, method: str, path: str) -> bool:
    """May ``role`` send ``method`` to ``path``?  (An unknown role may do nothing.)"""
    if role not in TABLE:
        return False
    matcher = _matcher(role, "GET" if method == "HEAD" else method)
    return matcher is not None and matcher.fullmatch(path) is not None


# ---- what each role may do, in an operator's words ----------------------------------------------------
# (key, what, method, a path it is asked for)
ACTIONS: tuple[tuple[str, str, str, str], ...] = (
    ("read", "read entities, data, operations, configurations, faults, logs, cyclic subscriptions, "
     "locks (`GET`)", "GET", "/api/v1/apps/x/data/x"),
    ("publish", "publish to a topic (`PUT …/data/{id}`)", "PUT", "/api/v1/apps/x/data/x"),
    ("operations", "run, control and cancel operations (`…/operations/{id}/executions`)", "POST",
     "/api/v1/apps/x/operations/x/executions"),
    ("cyclic_subscriptions", "make, change and delete cyclic subscriptions", "POST",
     "/api/v1/apps/x/cyclic-subscriptions"),
    ("locks", "acquire, extend and release locks", "POST", "/api/v1/apps/x/locks"),
    ("fault_clear", "clear faults (`DELETE …/faults`)", "DELETE", "/api/v1/apps/x/faults/x"),
    ("bulk_data", "upload and delete bulk data", "POST", "/api/v1/apps/x/bulk-data/x"),
    ("configurations", "change and reset configurations (`PUT`, `DELETE …/configurations`)", "PUT",
     "/api/v1/apps/x/configurations/x"),
    ("log_configuration", "change a log configuration (`PUT …/logs/configuration`)", "PUT",
     "/api/v1/apps/x/logs/configuration"),
    ("triggers", "make, change and delete triggers", "POST", "/api/v1/apps/x/triggers"),
    ("read_triggers", "read triggers and their events (`GET …/triggers`)", "GET", "/api/v1/apps/x/triggers"),
    ("audit", "read the audit trail (`GET /api/v1/x-medkit-audit`)", "GET", "/api/v1/x-medkit-audit"),
)


def summary(role: str) -> dict[str, bool]:
    """``{action key: may the role do it}`` for every entry of :data:`ACTIONS`."""
    return {key: allowed(role, method, path) for key, _what, method, path in ACTIONS}


README = Path(__file__).resolve().parents[2] / "README.md"
BEGIN = "<!-- roles: generated by `python -m app.auth.roles --write` from app/auth/roles.py; do not edit -->"
END = "<!-- roles: end -->"


def markdown() -> str:
    """The README's table: one row per action, one column per role."""
    lines = ["| may … | " + " | ".join(ROLES) + " |", "|---|" + "---|" * len(ROLES)]
    for key, what, _method, _path in ACTIONS:
        lines.append(f"| {what} | " + " | ".join("yes" if summary(role)[key] else "—" for role in ROLES) + " |")
    return "\n".join(lines) + "\n"


def documented(text: str) -> str | None:
    """The table between the README's markers, or None when they are missing."""
    start, end = text.find(BEGIN), text.find(END)
    if start < 0 or end < start:
        return None
    return text[start + len(BEGIN):end].strip("\n") + "\n"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv == ["--write"]:
        text = README.read_text()
        if documented(text) is None:
            print(f"{README}: the markers are missing", file=sys.stderr)
            return 1
        start, end = text.index(BEGIN) + len(BEGIN), text.index(END)
        README.write_text(text[:start] + "\n" + markdown() + text[end:])
        return 0
    print(markdown(), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
