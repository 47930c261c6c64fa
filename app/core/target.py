"""What a request is aimed at: its method, route family, entity and the path the role table reads.

One parse per request, shared by the checks every request passes through before its route runs,
and by the audit trail after it: the role check (``app/auth/``) matches :attr:`Target.role_path`
against medkit's permission table, the lock check (``app/locks/``) looks at :attr:`Target.family`
and the entity, and the audit trail (``app/audit/``) records them.  Nothing here knows a route by
name: a route's family is read from its URL rule, so a new route (bulk-data uploads, a fleet's
forwarded writes) is checked like every other the moment it is registered.

- ``/api/v1/{collection}/{entity_id}/{family}/...`` (``collection`` a literal or the rule's
  ``collection`` variable): that entity, that family (``data``, ``operations``,
  ``configurations``, ``faults``, ``logs``, ``cyclic-subscriptions``, ``triggers``, ``locks``,
  ``bulk-data`` ...); ``/api/v1/{collection}/{entity_id}`` is ``discovery``;
- ``/api/v1/{family}/...`` otherwise (``faults``, ``auth``, ``updates``, ``x-medkit-audit``,
  ``health`` ...), no entity; ``/api/v1/`` is ``root``; anything outside ``/api/v1`` is ``ui``
  or ``metrics``.

:attr:`Target.role_path` is the path with every variable of its rule but the collection turned
into one segment (``x``): medkit's table has one ``*`` for a data id or an operation id, which here
may hold slashes (``/apps/a/data/powertrain/engine/temperature``).  A request that matched no
route (404, 405) is read from its raw path, as medkit reads it.

The result is kept in the request's environ (:func:`of`); :func:`parse` is pure.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from typing import Any

from .entities import API_BASE, COLLECTIONS

WRITE_METHODS = frozenset({"POST", "PUT", "DELETE", "PATCH"})
# The collections a lock may scope (medkit's): the locks' (app/locks/) and the OpenAPI document's 409s.
LOCK_SCOPES = ("data", "operations", "configurations", "faults", "modes", "scripts", "bulk-data", "logs",
               "cyclic-subscriptions", "triggers")
ENVIRON_KEY = "sovd.target"
_VARIABLE = re.compile(r"<(?:[^<>]*:)?([A-Za-z_][A-Za-z0-9_]*)>")
# Converters whose value's slashes are segments to the role table (bulk data's ``{category}/{file_id}``),
# where every other variable is one segment; at most 3 are counted (3 matches no entry but admin's).
_SEGMENTED = re.compile(r"<bulk_rest:([A-Za-z_][A-Za-z0-9_]*)>")
_PREFIX = API_BASE + "/"


@dataclass(frozen=True, slots=True)
class Target:
    method: str
    family: str                 # the route family (see the module docstring)
    collection: str | None      # the entity's collection, when the path names an entity
    entity_id: str | None
    role_path: str              # what the role table is matched against
    rule: str | None            # the URL rule's template (None: no route matched)

    @property
    def write(self) -> bool:
        return self.method in WRITE_METHODS


@dataclass(frozen=True, slots=True)
class _Shape:
    """A URL rule, read once: where its collection, entity and family are."""

    collection: str | None      # a literal collection, or None
    collection_var: str | None  # the variable holding it
    entity_var: str | None
    family: str
    template: str               # the rule with {name} for each variable
    segmented: tuple[str, ...] = ()  # the variables counted segment by segment (_SEGMENTED)


@functools.lru_cache(maxsize=512)
def _shape(rule: str) -> _Shape:
    shape = _plain_shape(rule)
    segmented = tuple(_SEGMENTED.findall(rule))
    return _Shape(shape.collection, shape.collection_var, shape.entity_var, shape.family, shape.template,
                  segmented) if segmented else shape


def _plain_shape(rule: str) -> _Shape:
    template = _VARIABLE.sub(lambda m: "{" + m.group(1) + "}", rule)
    if not rule.startswith(_PREFIX):
        return _Shape(None, None, None, "metrics" if rule == "/metrics" else "ui", template)
    parts = rule[len(_PREFIX):].split("/")
    names = [(_VARIABLE.fullmatch(p).group(1) if _VARIABLE.fullmatch(p) else None) for p in parts]
    first, first_var = parts[0], names[0]
    if first_var == "collection" or first in COLLECTIONS:
        collection = None if first_var else first
        entity_var = names[1] if len(parts) > 1 else None
        if entity_var is None:
            family = "discovery" if len(parts) <= 2 else parts[1]
        else:
            family = parts[2] if len(parts) > 2 and names[2] is None else "discovery"
        return _Shape(collection, first_var, entity_var, family, template)
    return _Shape(None, None, None, first or "root", template)


def parse(method: str, path: str, rule: str | None, view_args: dict[str, Any] | None) -> Target:
    """The target of ``method`` on ``path`` (``rule`` and ``view_args``: the matched route's, if any)."""
    if rule is None:
        return _raw(method, path)
    shape = _shape(rule)
    args = view_args or {}
    collection = shape.collection or (str(args.get(shape.collection_var)) if shape.collection_var else None)
    entity_id = args.get(shape.entity_var) if shape.entity_var else None
    values = {name: "x" for name in args}
    for name in shape.segmented:
        values[name] = "/".join(["x"] * min(3, len(str(args.get(name, "")).strip("/").split("/"))))
    if shape.collection_var:
        values[shape.collection_var] = collection
    try:
        role_path = shape.template.format_map(values)
    except (KeyError, IndexError, ValueError):
        role_path = path
    return Target(method, shape.family, collection, None if entity_id is None else str(entity_id),
                  role_path, rule)


def _raw(method: str, path: str) -> Target:
    if not path.startswith(_PREFIX):
        return Target(method, "metrics" if path == "/metrics" else "ui", None, None, path, None)
    parts = path[len(_PREFIX):].split("/")
    if parts[0] in COLLECTIONS and len(parts) > 1 and parts[1]:
        family = parts[2] if len(parts) > 2 and parts[2] else "discovery"
        return Target(method, family, parts[0], parts[1], path, None)
    return Target(method, parts[0] or "root", None, None, path, None)


def of(req) -> Target:
    """The target of the Flask request ``req`` (parsed once, kept in its environ)."""
    target = req.environ.get(ENVIRON_KEY)
    if target is None:
        rule = req.url_rule
        target = parse(req.method, req.path, rule.rule if rule is not None else None, req.view_args)
        req.environ[ENVIRON_KEY] = target
    return target
