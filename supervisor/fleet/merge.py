"""The fleet's entity tree: the robots' trees merged as medkit's ``EntityMerger`` merges its peers'.

Pure functions over plain data (the robots' listings as they sent them), so every rule is
unit-testable.  The fleet gateway has no entity of its own: the robots are merged one after the
other, in the order the fleet first saw them (so a robot that joins later never renames what an
earlier one offered), starting from an empty tree.  medkit's rules (``entity_merger.cpp``,
``docs/config/aggregation.rst``):

- **areas, functions**: merged by id; a merged function's ``hosts`` are the union of its robots'
  (each robot's renamed apps remapped first).  An area or function that one robot alone offers is
  that robot's (routed to it); one that several offer is served here with the merged view and its
  collections are fanned out to those robots.  (medkit keeps the first peer's routing entry on an
  aggregator with no local entities; the fleet does not, so a function that spans robots is never
  answered by one of them alone.)
- **components**: merged by id; a component is a leaf (the fleet knows no parent components), so it
  is routed to the robot that offered it last, and one offered by several robots is reported in
  ``/health``'s ``warnings`` as ``leaf_id_collision`` (medkit's last-writer-wins).
- **apps**: an id already taken is renamed ``<fleet_id>__<id>`` (and its name likewise); every app
  is routed to its robot, under its own id there.

Every entity carries ``x-medkit.contributors`` (``peer:<fleet_id>``, sorted) and ``x-medkit.source``
(``peer:<fleet_id>`` of the robot that first offered it); an entity of a robot that is not
connected is retained with ``x-medkit.available: false`` (and an app's ``is_online: false``).

A robot's tree is checked before it is merged (:func:`tree_problem`): medkit's limits (ids of
``[A-Za-z0-9_-]{1,256}``, at most ``MAX_PER_COLLECTION`` entities per collection); a tree that breaks
them is not taken, and the robot's last good one stays.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import orjson

from ipc.fleet import API, COLLECTIONS, SEPARATOR

MAX_PER_COLLECTION = 1000
_ID = re.compile(r"^[A-Za-z0-9_-]{1,256}$")
GROUPINGS = ("areas", "functions")
TYPES = {"areas": "Area", "components": "Component", "apps": "App", "functions": "Function"}
WRONG_TYPE_ORDER = ("components", "apps", "areas", "functions")  # medkit's get_entity_info order
LEAF_COLLISION = "leaf_id_collision"


@dataclass
class RobotTree:
    name: str
    order: int                      # when the fleet first saw the robot: the merge order
    available: bool
    collections: dict[str, list[dict[str, Any]]]


@dataclass
class Merged:
    generation: int
    items: dict[str, dict[str, dict[str, Any]]]            # collection -> id -> the fleet's item
    routes: dict[tuple[str, str], tuple[str, str]]         # (collection, id) -> (robot, its id there)
    contributors: dict[tuple[str, str], list[str]]         # (collection, id) -> robots, merge order
    renamed: dict[str, dict[str, str]]                     # robot -> its app id -> the fleet's
    warnings: list[dict[str, Any]]
    _bodies: dict[str, bytes] = field(default_factory=dict)

    def listing(self, collection: str) -> bytes:
        """The body of ``GET /api/v1/<collection>``, serialized once per tree."""
        body = self._bodies.get(collection)
        if body is None:
            entries = self.items.get(collection, {})
            items = [entries[k] for k in sorted(entries)]
            body = self._bodies[collection] = orjson.dumps({"items": items,
                                                            "x-medkit": {"total_count": len(items)}})
        return body

    def entity(self, collection: str, entity_id: str) -> dict[str, Any] | None:
        item = self.items.get(collection, {}).get(entity_id)
        if item is None:
            return None
        key = (collection, entity_id)
        out: dict[str, Any] = {"item": item, "route": self.routes.get(key),
                               "contributors": list(self.contributors.get(key, []))}
        if collection == "functions" and key not in self.routes:
            apps = self.items["apps"]
            out["hosts"] = [apps[h] for h in item.get("hosts") or [] if h in apps]
        return out

    def elsewhere(self, collection: str, entity_id: str) -> str | None:
        """The type name of the entity with this id in another collection (for the wrong-type 400)."""
        for name in WRONG_TYPE_ORDER:
            if name != collection and entity_id in self.items.get(name, {}):
                return TYPES[name]
        return None

    def member_id(self, robot: str, member: str) -> str:
        """medkit's ``local_member_id``: the fleet's id of app ``member`` of ``robot``."""
        return self.renamed.get(robot, {}).get(member, member)

    @property
    def size(self) -> int:
        return sum(len(v) for v in self.items.values())


def tree_problem(tree: Any) -> str | None:
    """Why a robot's tree (its four listings) cannot be merged, or None."""
    if not isinstance(tree, dict):
        return "not a JSON object"
    for collection in COLLECTIONS:
        items = tree.get(collection)
        if not isinstance(items, list):
            return f"{collection}: not a list"
        if len(items) > MAX_PER_COLLECTION:
            return f"{collection}: {len(items)} entities (at most {MAX_PER_COLLECTION})"
        for item in items:
            if not isinstance(item, dict) or not isinstance(item.get("id"), str) or not _ID.match(item["id"]):
                return f"{collection}: an entity without a valid id"
    return None


def _peer(robot: str) -> str:
    return "peer:" + robot


def _adopt(collection: str, item: dict[str, Any], robot: str, available: bool, entity_id: str,
           name: Any) -> dict[str, Any]:
    out = dict(item)
    out["id"] = entity_id
    out["name"] = name
    out["href"] = f"{API}/{collection}/{entity_id}"
    ext = dict(item["x-medkit"]) if isinstance(item.get("x-medkit"), dict) else {}
    ext["source"] = _peer(robot)
    if not available:
        ext["available"] = False
        if collection == "apps":
            ext["is_online"] = False
    out["x-medkit"] = ext
    return out


def _union(into: dict[str, Any], key: str, more: Any) -> None:
    if isinstance(more, list):
        have = into.get(key) if isinstance(into.get(key), list) else []
        into[key] = have + [v for v in more if v not in have]


def _fold(have: dict[str, Any], item: dict[str, Any], available: bool) -> None:
    """A robot's copy of an entity already in the tree: tags (and hosts) joined, a description kept."""
    _union(have, "tags", item.get("tags"))
    if not have.get("description") and item.get("description"):
        have["description"] = item["description"]
    if available and have["x-medkit"].get("available") is False:
        del have["x-medkit"]["available"]   # reachable through this robot


def merge(trees: list[RobotTree], generation: int) -> Merged:
    items: dict[str, dict[str, dict[str, Any]]] = {c: {} for c in COLLECTIONS}
    routes: dict[tuple[str, str], tuple[str, str]] = {}
    contributors: dict[tuple[str, str], list[str]] = {}
    renamed: dict[str, dict[str, str]] = {}
    claims: dict[str, list[str]] = {}

    def add(collection: str, item: dict[str, Any], robot: str, available: bool, entity_id: str, name: Any):
        have = items[collection].get(entity_id)
        if have is None:
            items[collection][entity_id] = _adopt(collection, item, robot, available, entity_id, name)
        else:
            _fold(have, item, available)
        robots = contributors.setdefault((collection, entity_id), [])
        if robot not in robots:
            robots.append(robot)
        return items[collection][entity_id]

    for tree in sorted(trees, key=lambda t: t.order):
        robot, available, lists = tree.name, tree.available, tree.collections
        for item in lists.get("areas") or []:
            add("areas", item, robot, available, item["id"], item.get("name", item["id"]))
        for item in lists.get("components") or []:
            add("components", item, robot, available, item["id"], item.get("name", item["id"]))
            routes[("components", item["id"])] = (robot, item["id"])   # last writer
            claims.setdefault(item["id"], [])
            if robot not in claims[item["id"]]:
                claims[item["id"]].append(robot)
        remap: dict[str, str] = {}
        seen: set[str] = set()
        for item in lists.get("apps") or []:
            app_id, name = item["id"], item.get("name", item["id"])
            if app_id in seen:
                continue  # the robot offered the same app twice
            seen.add(app_id)
            if app_id in items["apps"]:
                remap[app_id] = f"{robot}{SEPARATOR}{app_id}"
                name = f"{robot}{SEPARATOR}{name}"
            fleet_id = remap.get(app_id, app_id)
            add("apps", item, robot, available, fleet_id, name)
            routes[("apps", fleet_id)] = (robot, app_id)
        renamed[robot] = remap
        for item in lists.get("functions") or []:
            hosts = [remap.get(h, h) for h in item.get("hosts") or [] if isinstance(h, str)]
            merged = add("functions", {**item, "hosts": hosts}, robot, available, item["id"],
                         item.get("name", item["id"]))
            if merged.get("hosts") is not hosts:
                _union(merged, "hosts", hosts)
                if isinstance(merged["x-medkit"].get("hosts"), list):
                    merged["x-medkit"]["hosts"] = list(merged["hosts"])

    for collection in GROUPINGS:   # one robot's grouping is that robot's; several robots': served here
        for entity_id in items[collection]:
            robots = contributors[(collection, entity_id)]
            if len(robots) == 1:
                routes[(collection, entity_id)] = (robots[0], entity_id)
    for (collection, entity_id), robots in contributors.items():
        items[collection][entity_id]["x-medkit"]["contributors"] = sorted(_peer(r) for r in robots)
    warnings = [{
        "code": LEAF_COLLISION,
        "message": (f"Component '{cid}' is announced by multiple peers ({', '.join(robots)}); routing falls "
                    "back to last-writer-wins, which depends on the order the robots joined. Resolve by "
                    "giving each robot's host a name of its own."),
        "entity_ids": [cid],
        "peer_names": list(robots),
    } for cid, robots in sorted(claims.items()) if len(robots) > 1]
    return Merged(generation, items, routes, contributors, renamed, warnings)
