"""The ROS graph as SOVD entities (runtime-only discovery): pure functions.

Input is the ROS worker's ``graph`` answer (``ipc/PROTOCOL.md``); output is an
:class:`Entities` index that the routes read.  Nothing here talks to a socket
or to ROS, so every rule of the entity model (medkit's, README "What you get
over HTTP") is unit-testable:

- no areas;
- one component, the host (id from the hostname, see :func:`host_component_id`);
- one app per ROS node, hidden nodes (name starting with ``_``) left out; the
  id is the node name, or ``<namespace with / turned into _>_<name>`` when the
  same name exists in several namespaces;
- one function per first namespace segment (``root`` for the root namespace),
  hosting the apps below it;
- an app's data items are its node's topics (published and subscribed); a
  component's or function's are the union over its apps;
- relations (:data:`RELATIONS`, medkit's HATEOAS collections): a component
  hosts its apps, a function hosts the apps below its namespace, an app is
  located on the host; nothing has subcomponents, dependencies or an area.
"""

from __future__ import annotations

import platform
import re
import socket
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

API_BASE = "/api/v1"
ENTITY_ID_MAX = 256

# collection (URL segment) -> (listing "type", type name used in error bodies)
KINDS = {
    "areas": ("area", "Area"),
    "components": ("component", "Component"),
    "apps": ("app", "App"),
    "functions": ("function", "Function"),
}
COLLECTIONS = tuple(KINDS)
# collection -> name of its id in paths, OpenAPI and medkit's typed error parameters
PARAM_NAMES = {"areas": "area_id", "components": "component_id", "apps": "app_id",
               "functions": "function_id"}
# Where medkit looks for an id of the wrong type (``get_entity_info`` without a type).
WRONG_TYPE_ORDER = ("components", "apps", "areas", "functions")
ROOT_FUNCTION = "root"

# Resource collections linked from component, app and function details (medkit's order; operations, configurations,
# faults, logs and triggers). ``logs`` and ``triggers`` come later in medkit's lists, see Entity.detail.
SERVED_RESOURCES = ("operations", "configurations", "faults")

# The relation collections medkit serves under an entity:
# (owner collection, relation) -> (collection of the listed entities, ``_links`` name of the owner).
RELATIONS = {
    ("areas", "components"): ("components", "area"),
    ("areas", "contains"): ("components", "area"),
    ("areas", "subareas"): ("areas", "parent"),
    ("components", "subcomponents"): ("components", "parent"),
    ("components", "hosts"): ("apps", "component"),
    ("components", "depends-on"): ("components", "component"),
    ("apps", "is-located-on"): ("components", "app"),
    ("apps", "belongs-to"): ("areas", "app"),
    ("apps", "depends-on"): ("apps", "app"),
    ("functions", "hosts"): ("apps", "function"),
}


# --------------------------------------------------------------------------- host


@dataclass(frozen=True)
class HostInfo:
    hostname: str
    pretty_name: str
    machine: str

    @property
    def component_id(self) -> str:
        return host_component_id(self.hostname)

    @property
    def description(self) -> str:
        return f"{self.pretty_name} on {self.machine}"


def host_component_id(hostname: str) -> str:
    """Lower-case, ``.`` and space to ``_``, drop anything but ``[a-z0-9_-]``, cut to 256."""
    text = hostname.lower().replace(".", "_").replace(" ", "_")
    text = re.sub(r"[^a-z0-9_-]", "", text)[:ENTITY_ID_MAX]
    return text or "unknown_host"


def os_pretty_name(paths: Iterable[str] = ("/etc/os-release", "/usr/lib/os-release")) -> str:
    """``PRETTY_NAME`` of os-release, or ``"Linux"`` when there is none."""
    for path in paths:
        try:
            with open(path, encoding="utf-8", errors="replace") as fh:
                lines = fh.read().splitlines()
        except OSError:
            continue
        for line in lines:
            key, sep, value = line.partition("=")
            if sep and key.strip() == "PRETTY_NAME":
                value = value.strip()
                if len(value) >= 2 and value[0] == value[-1] and value[0] in "\"'":
                    value = value[1:-1]
                if value:
                    return value
    return platform.system() or "Linux"


def host_info(hostname: str | None = None) -> HostInfo:
    return HostInfo(hostname if hostname is not None else socket.gethostname(),
                    os_pretty_name(), platform.machine() or "unknown")


# --------------------------------------------------------------------------- entities


@dataclass
class DataTopic:
    """One data item of an entity: a topic, its type and who uses it."""

    name: str
    type: str | None
    publish: bool = False
    subscribe: bool = False
    members: set[str] = field(default_factory=set)

    @property
    def direction(self) -> str:
        if self.publish and self.subscribe:
            return "both"
        return "publish" if self.publish else "subscribe"


@dataclass
class Entity:
    collection: str
    id: str
    name: str
    x_medkit: dict[str, Any]
    topics: dict[str, DataTopic] = field(default_factory=dict)
    description: str | None = None
    hosts: list[str] | None = None          # functions: the app ids
    component_id: str | None = None         # apps: the host component
    app_ids: list[str] = field(default_factory=list)  # components/functions: the apps they aggregate

    @property
    def type(self) -> str:
        return KINDS[self.collection][0]

    @property
    def type_name(self) -> str:
        return KINDS[self.collection][1]

    @property
    def href(self) -> str:
        return f"{API_BASE}/{self.collection}/{self.id}"

    @property
    def aggregated(self) -> bool:
        return self.collection != "apps"

    def listing_item(self) -> dict[str, Any]:
        item: dict[str, Any] = {"id": self.id, "name": self.name, "href": self.href, "type": self.type}
        if self.description is not None:
            item["description"] = self.description
        if self.hosts is not None:
            item["hosts"] = list(self.hosts)
        item["x-medkit"] = self.x_medkit
        return item

    def detail(self) -> dict[str, Any]:
        """The entity detail with medkit's URIs, ``capabilities`` and ``_links``.

        Only what this gateway serves is linked: ``status`` (apps and components),
        ``data``, ``operations``, ``configurations``, ``faults``, ``logs``,
        ``triggers`` and the relation collections, in medkit's order
        (``discovery_handlers.cpp``).  As in medkit, ``depends-on`` is linked only when there are
        dependencies (never, in runtime discovery) and an app's ``belongs-to``
        only when it has a host component; a function's ``hosts`` is the URI of
        its hosts collection (the app ids are in ``x-medkit.hosts``).
        """
        base = self.href
        body: dict[str, Any] = {"id": self.id, "name": self.name, "type": self.type}
        if self.description is not None:
            body["description"] = self.description
        links = {"self": base, "collection": f"{API_BASE}/{self.collection}"}
        caps: list[str]
        ext = dict(self.x_medkit)
        served = {name: f"{base}/{name}" for name in SERVED_RESOURCES}
        if self.collection == "areas":
            body.update(subareas=base + "/subareas", components=base + "/components",
                        contains=base + "/contains", data=base + "/data")
            caps = ["subareas", "contains", "data"]
        elif self.collection == "components":
            body.update(status=base + "/status", data=base + "/data", **served, subcomponents=base + "/subcomponents",
                        hosts=base + "/hosts", logs=base + "/logs", triggers=base + "/triggers")
            caps = ["status", "data", *SERVED_RESOURCES, "logs", "subcomponents", "hosts", "triggers"]
        elif self.collection == "apps":
            body.update(status=base + "/status", data=base + "/data")
            body.update(served, logs=base + "/logs", triggers=base + "/triggers")
            caps = ["status", "data", *SERVED_RESOURCES, "logs", "triggers"]
            if self.component_id is not None:
                located = f"{API_BASE}/components/{self.component_id}"
                body["is-located-on"] = located
                body["belongs-to"] = base + "/belongs-to"
                links["is-located-on"] = located
                links["belongs-to"] = base + "/belongs-to"
                caps += ["is-located-on", "belongs-to"]
        else:
            body.update(hosts=base + "/hosts", data=base + "/data", **served, logs=base + "/logs",
                        triggers=base + "/triggers")
            caps = ["hosts", "data", *SERVED_RESOURCES, "logs", "triggers"]
            ext["hosts"] = list(self.hosts or [])
        capabilities = [{"name": name, "href": f"{base}/{name}"} for name in caps]
        if self.collection == "components":
            ext["capabilities"] = capabilities  # medkit repeats them there for x-medkit-only tools
        body["capabilities"] = capabilities
        body["_links"] = links
        body["x-medkit"] = ext
        return body


@dataclass
class Entities:
    generation: int
    host_id: str
    collections: dict[str, dict[str, Entity]]
    topics: dict[str, dict[str, Any]]       # the graph's topic table, by name

    def get(self, collection: str, entity_id: str) -> Entity | None:
        return self.collections.get(collection, {}).get(entity_id)

    def elsewhere(self, collection: str, entity_id: str) -> Entity | None:
        """The entity with this id in another collection (for the wrong-type error)."""
        for name in WRONG_TYPE_ORDER:
            if name != collection and entity_id in self.collections[name]:
                return self.collections[name][entity_id]
        return None

    def related(self, owner: Entity, relation: str) -> list[Entity]:
        """The entities of ``owner``'s relation collection (see :data:`RELATIONS`)."""
        target = RELATIONS[(owner.collection, relation)][0]
        if (owner.collection, relation) in (("components", "hosts"), ("functions", "hosts")):
            ids = owner.app_ids
        elif relation == "is-located-on":
            ids = [owner.component_id] if owner.component_id else []
        else:
            ids = []  # runtime discovery knows no areas, subcomponents or dependencies
        return [e for e in (self.get(target, i) for i in ids) if e is not None]

    def relation_body(self, owner: Entity, relation: str) -> dict[str, Any]:
        """The body of ``GET {owner}/{relation}``: medkit's items, total and ``_links``."""
        items = [e.listing_item() for e in self.related(owner, relation)]
        owner_link = RELATIONS[(owner.collection, relation)][1]
        return {"items": items, "x-medkit": {"total_count": len(items)},
                "_links": {"self": f"{owner.href}/{relation}", owner_link: owner.href}}

    def listing(self, collection: str) -> list[Entity]:
        return [self.collections[collection][k] for k in sorted(self.collections[collection])]


def _ns_prefix(namespace: str) -> str:
    return namespace.strip("/").replace("/", "_")


def app_ids(nodes: list[dict[str, Any]]) -> dict[str, str]:
    """fqn -> app id for the visible nodes (see the module docstring for the rule).

    Plain node names are given out first, so a derived id never takes the id
    of a node that is named like it; a clash left over gets ``_2``, ``_3`` ...
    """
    fqns = sorted({n["fqn"]: n for n in nodes}.items())
    counts: dict[str, int] = {}
    for _, n in fqns:
        counts[n["name"]] = counts.get(n["name"], 0) + 1
    wanted: dict[str, str] = {}
    for fqn, n in fqns:
        prefix = _ns_prefix(n["namespace"]) if counts[n["name"]] > 1 else ""
        wanted[fqn] = (f"{prefix}_{n['name']}" if prefix else n["name"])[:ENTITY_ID_MAX]
    ids: dict[str, str] = {}
    used: set[str] = set()
    plain_first = sorted(fqns, key=lambda item: (wanted[item[0]] != item[1]["name"], item[0]))
    for fqn, _ in plain_first:
        candidate, k = wanted[fqn], 1
        while candidate in used:
            k += 1
            suffix = f"_{k}"
            candidate = wanted[fqn][:ENTITY_ID_MAX - len(suffix)] + suffix
        used.add(candidate)
        ids[fqn] = candidate
    return ids


def function_id(namespace: str) -> str:
    first = namespace.strip("/").split("/", 1)[0]
    return first or ROOT_FUNCTION


def _visible(node: Any) -> bool:
    return (isinstance(node, dict) and isinstance(node.get("name"), str) and node["name"]
            and not node["name"].startswith("_") and isinstance(node.get("namespace"), str)
            and isinstance(node.get("fqn"), str))


def _unique(nodes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One entry per fqn: ROS allows two nodes with one name; they make one app."""
    by_fqn: dict[str, dict[str, Any]] = {}
    for n in nodes:
        have = by_fqn.get(n["fqn"])
        if have is None:
            by_fqn[n["fqn"]] = n
        else:
            by_fqn[n["fqn"]] = {**have, **{k: _pairs(have.get(k)) + _pairs(n.get(k))
                                           for k in ("publishes", "subscribes")}}
    return list(by_fqn.values())


def _pairs(value: Any) -> list[tuple[str, str | None]]:
    out = []
    for pair in value if isinstance(value, list) else []:
        if isinstance(pair, (list, tuple)) and pair and isinstance(pair[0], str):
            out.append((pair[0], pair[1] if len(pair) > 1 and isinstance(pair[1], str) else None))
    return out


def _merge(into: dict[str, DataTopic], topic: DataTopic, member: str) -> None:
    have = into.get(topic.name)
    if have is None:
        have = into[topic.name] = DataTopic(topic.name, topic.type)
    have.publish |= topic.publish
    have.subscribe |= topic.subscribe
    have.type = have.type or topic.type
    have.members.add(member)


def build(graph: dict[str, Any], host: HostInfo) -> Entities:
    """Turn one ``graph`` answer into the entity index."""
    host_id = host.component_id
    nodes = _unique([n for n in graph.get("nodes") or [] if _visible(n)])
    topic_table = {t["name"]: t for t in graph.get("topics") or []
                   if isinstance(t, dict) and isinstance(t.get("name"), str)}
    ids = app_ids(nodes)

    apps: dict[str, Entity] = {}
    for node in nodes:
        app_id = ids[node["fqn"]]
        topics: dict[str, DataTopic] = {}
        for direction in ("publishes", "subscribes"):
            for name, type_ in _pairs(node.get(direction)):
                item = topics.get(name) or DataTopic(name, type_)
                item.type = item.type or type_ or _first_type(topic_table.get(name))
                if direction == "publishes":
                    item.publish = True
                else:
                    item.subscribe = True
                item.members.add(app_id)
                topics[name] = item
        apps[app_id] = Entity(
            "apps", app_id, node["name"],
            {"source": "heuristic", "is_online": True, "component_id": host_id,
             "ros2": {"node": node["fqn"]}},
            topics=topics, component_id=host_id,
        )

    component = Entity("components", host_id, host.hostname, {"source": "runtime"},
                       description=host.description)
    functions: dict[str, Entity] = {}
    node_by_app = {ids[n["fqn"]]: n for n in nodes}
    for app_id in sorted(apps):
        app = apps[app_id]
        fid = function_id(node_by_app[app_id]["namespace"])
        func = functions.get(fid)
        if func is None:
            func = functions[fid] = Entity("functions", fid, fid, {"source": "runtime"}, hosts=[])
        func.hosts.append(app_id)
        func.app_ids.append(app_id)
        component.app_ids.append(app_id)
        for topic in app.topics.values():
            _merge(component.topics, topic, app_id)
            _merge(func.topics, topic, app_id)

    generation = graph.get("generation")
    return Entities(
        generation=generation if isinstance(generation, int) else -1,
        host_id=host_id,
        collections={"areas": {}, "components": {host_id: component}, "apps": apps,
                     "functions": functions},
        topics=topic_table,
    )


def _first_type(topic: dict[str, Any] | None) -> str | None:
    types = (topic or {}).get("types")
    if isinstance(types, list) and types and isinstance(types[0], str):
        return types[0]
    return None


def data_items(entity: Entity, type_info: dict[str, dict[str, Any] | None]) -> dict[str, Any]:
    """The body of ``GET {entity}/data``; ``type_info`` maps a type to its info (None: unknown)."""
    items = []
    for name in sorted(entity.topics):
        topic = entity.topics[name]
        ros2: dict[str, Any] = {"topic": name}
        if topic.type:
            ros2["type"] = topic.type
        ros2["direction"] = topic.direction
        ext: dict[str, Any] = {"ros2": ros2}
        info = type_info.get(topic.type) if topic.type else None
        if info is not None:
            ext["type_info"] = {"schema": info.get("schema"), "default_value": info.get("default_value")}
        if entity.aggregated:
            ext["member_ids"] = sorted(topic.members)
        items.append({"id": name, "name": name, "category": "currentData", "x-medkit": ext})
    ext = {"entity_id": entity.id, "total_count": len(items)}
    if entity.aggregated:
        sources = sorted(entity.app_ids)
        ext.update({"aggregated": True, "aggregation_sources": sources,
                    "aggregation_level": entity.type})
    return {"items": items, "x-medkit": ext}
