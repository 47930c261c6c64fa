"""What cyclic subscriptions and triggers may watch of the families' resources (the HTTP side).

A cyclic subscription or a trigger names a resource by its URI
(``/api/v1/{apps|components|functions}/{id}/{collection}[/{path}][?query]``).
:func:`parse_resource` checks what every such URI must be (medkit's rules and
texts: a path, no control characters, valid percent-encoding, no traversal, the
route's entity); the collection is then the business of the family that
registered it, and the subscriptions and triggers families know none of them:

- :class:`Streamable` (``streamable(app, ...)`` in a family's setup): a
  collection a cyclic subscription may stream (``data``, ``operations``'
  executions, ``configurations``): how its URI becomes ``sub_create``'s
  arguments (its kind and target on the ROS worker, whose samplers stream it),
  and how a frame of each of its kinds becomes the body a GET of the resource
  answers (its payload, or its error);
- :class:`Observable` (``observable(app, ...)``): a collection a trigger may
  observe (``data``, ``faults``, ``logs``): how its URI becomes the trigger's
  ``target`` and bytes mode on the ROS worker (whose notifier the family
  provides the collection to);
- :class:`Relayed` (``relayed(app, ...)`` in a family's ``offer``): a collection
  a gateway that relays other gateways (the fleet gateway, ``app/fleet/``: the
  robots' answers through its link) serves with the family's rules: its query
  checks and its event stream, read from another channel.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import unquote, urlsplit

from flask import Flask, current_app, request

from ipc.errors import IpcError

from .common import BAD_PERCENT, node_names
from .entities import Entity
from .errors import ApiError

MAX_RESOURCE_LENGTH = 4096
_RESOURCE = re.compile(r"^/api/v1/([^/?#]+)/([^/?#]+)/([^/?#]+)(/.*)?$")
UNKNOWN_CLIENT = "unknown"
STREAMABLE = "sovd_streamable"
OBSERVABLE = "sovd_observable"
RELAYED = "sovd_relayed"


def bad(message: str, parameter: str, value: Any, **extra: Any) -> ApiError:
    return ApiError(400, "invalid-parameter", message, {"parameter": parameter, "value": value, **extra})


def vendor(code: str, message: str, params: dict[str, Any]) -> ApiError:
    return ApiError(400, "vendor-error", message, params, vendor_code=code)


def client() -> str:
    """Whose subscription or trigger this is, for the per-client caps: the address that
    ``core/clientaddr.py`` resolved (read from the environ: Werkzeug's ``request.remote_addr`` is
    read before that resolution).  A listener without peer addresses (a UNIX socket with no
    trusted proxy in front) gives none; its clients share one name instead of being refused."""
    return (request.environ.get("REMOTE_ADDR") or UNKNOWN_CLIENT)[:256]


@dataclass(frozen=True)
class Resource:
    """A checked resource URI: ``what`` (its collection, percent-encoded), ``rest`` (the path after it,
    still percent-encoded: ``""`` or ``/...``) and ``query``."""

    text: str
    collection: str
    entity_id: str
    what: str
    rest: str
    query: str

    def invalid(self, why: str) -> ApiError:
        """400 ``x-medkit-invalid-resource-uri``, saying ``why``."""
        return invalid(self.text, why)


def invalid(resource: str, why: str) -> ApiError:
    return vendor("x-medkit-invalid-resource-uri", "Invalid resource URI: " + why,
                  {"parameter": "resource", "value": resource[:300]})


def parse_resource(resource: Any, collection: str, entity_id: str) -> Resource:
    """The resource URI a client sent for an entity's subscription or trigger, checked as medkit checks it."""
    if resource is None:
        raise bad("resource: missing required field", "resource", None)
    if not isinstance(resource, str) or not resource or len(resource) > MAX_RESOURCE_LENGTH:
        raise bad(f"resource: must be a URI path of 1 to {MAX_RESOURCE_LENGTH} characters", "resource",
                  str(resource)[:300])
    if any(ord(c) < 0x20 or c == "\x7f" for c in resource):
        raise invalid(resource, "it contains control characters")
    parts = urlsplit(resource)
    if parts.scheme or parts.netloc or parts.fragment:
        raise invalid(resource, "give the path only (/api/v1/{apps|components|functions}/{id}/data/{topic})")
    if BAD_PERCENT.search(parts.path):
        raise invalid(resource, "it contains an invalid percent-encoding")
    match = _RESOURCE.match(parts.path)
    if not match or match.group(1) not in ("apps", "components", "functions"):
        raise invalid(resource, "Resource URI must match /api/v1/{apps|components|functions}/{id}/{collection}[/{path}]")
    try:
        decoded = [unquote(part, errors="strict") for part in parts.path.split("/")]
    except UnicodeDecodeError:
        raise invalid(resource, "it does not decode to UTF-8") from None
    if any(seg in ("..", ".") for part in decoded for seg in part.split("/")):
        raise invalid(resource, "Resource path must not contain '..' as a path segment")
    kind, rid = match.group(1), unquote(match.group(2))
    if kind != collection or rid != entity_id:
        raise vendor("x-medkit-entity-mismatch", "Resource URI must reference the same entity as the route",
                     {"parameter": "resource", "value": resource[:300]})
    return Resource(resource, collection, entity_id, match.group(3), match.group(4) or "", parts.query)


# ---- the registries -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Streamable:
    """A collection cyclic subscriptions may stream (see the module's docstring).

    ``resolve(resource, entity)``: ``sub_create``'s arguments for it (``topic`` and ``bytes`` for a
    topic; ``kind``, ``target`` and ``bytes`` for another kind), or the error a GET of it would answer.
    ``payload(stream, meta, data)``: the body a GET answers for one frame of a kind in ``kinds``;
    ``error(stream, exc)``: the error body a GET answers for ``exc``; ``opening(stream)``: what to do
    in the stream's request before its first frame (fill a cache the reader reads)."""

    collection: str
    kinds: tuple[str, ...]
    resolve: Callable[[Resource, Entity], dict[str, Any]]
    payload: Callable[[Any, dict[str, Any], bytes], bytes]
    error: Callable[[Any, IpcError], bytes]
    opening: Callable[[Any], None] | None = None


@dataclass(frozen=True)
class Observable:
    """A collection triggers may observe: ``resolve(resource, entity, condition, path)`` -> ``(target,
    bytes mode)`` of the trigger on the ROS worker (``source`` is the collection's name there)."""

    collection: str
    resolve: Callable[[Resource, Entity, dict[str, Any], str], tuple[str, str]]
    source: str = field(default="")


@dataclass(frozen=True)
class Relayed:
    """A collection a relaying gateway serves with the family's rules (see the module's docstring).

    ``check(params)``: the request's query checked as the family checks it (its 400, whose parameters
    include ``params``: the entity asked); ``stream(app, name, client, command, endpoint, label)``:
    registers the hub ``name`` of the collection's event stream, read from the channel at
    ``endpoint(runtime_dir)``, missed events replayed by ``command`` of ``app.extensions[client]``;
    ``response(name, max_streams)``: the answer to a GET of that hub's stream."""

    collection: str
    check: Callable[[dict[str, Any] | None], Any]
    stream: Callable[..., None]
    response: Callable[[str, int], Any]


RANGES = ("EnterRange", "LeaveRange")


def scope(entity: Entity, resource: Resource, condition: dict[str, Any], path: str, event: str,
          example: str, **extra: Any) -> tuple[str, str]:
    """The target of a trigger on an event-driven collection (faults, logs): the entity's scope, its nodes
    (``{"nodes": [...], **extra}``, as the ROS worker's ``parse_scope`` reads it), bytes mode ``array``.

    A condition that cannot apply is refused: a change of these collections (an ``event``) is an object,
    never a number, so ``EnterRange``/``LeaveRange`` need a ``path`` to a number in it (``example``)."""
    if condition["condition_type"] in RANGES and not path:
        raise ApiError(400, "invalid-parameter",
                       f"{condition['condition_type']} on {resource.what} needs a 'path' to a number in the payload "
                       f"(a {event} is an object), e.g. {example}", {"parameter": "path"})
    return json.dumps({"nodes": node_names(entity), **extra}, separators=(",", ":")), "array"


def streamable(app: Flask, item: Streamable) -> None:
    """A family's setup: cyclic subscriptions may stream ``item.collection``."""
    app.extensions.setdefault(STREAMABLE, {})[item.collection] = item


def observable(app: Flask, item: Observable) -> None:
    """A family's setup: triggers may observe ``item.collection``."""
    app.extensions.setdefault(OBSERVABLE, {})[item.collection] = item


def relayed(app: Flask, item: Relayed) -> None:
    """A family's offer: a relaying gateway may serve ``item.collection`` with the family's rules."""
    app.extensions.setdefault(RELAYED, {})[item.collection] = item


def relays(app: Flask | None = None) -> dict[str, Relayed]:
    return (app or current_app).extensions.get(RELAYED, {})


def streamables(app: Flask | None = None) -> dict[str, Streamable]:
    return (app or current_app).extensions.get(STREAMABLE, {})


def observables(app: Flask | None = None) -> dict[str, Observable]:
    return (app or current_app).extensions.get(OBSERVABLE, {})


def stream_kinds(app: Flask) -> dict[str, Streamable]:
    """kind (as the ROS worker names it) -> the streamable that renders its frames."""
    return {kind: item for item in streamables(app).values() for kind in item.kinds}
