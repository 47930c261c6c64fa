"""The data family's topics as cyclic subscriptions stream them and triggers observe them (``core/resources.py``).

A resource ``…/data/{topic}[?bytes=base64]`` names a topic, spelled as the data
route accepts it; a subscription's frames are exactly the body a GET of it
answers (``model.py``), its ``type_info`` from the process's cache (filled when a
stream opens: the reader never waits on IPC).
"""

from __future__ import annotations

import logging
from typing import Any
from urllib.parse import parse_qsl, unquote

import gevent
import orjson
from flask import Flask

from ipc.errors import IpcError
from ipc.protocol import BYTES_MODES
from ipc.topics import InvalidTopic, normalize_topic

from ..core import resources, rosclient
from ..core.entities import Entity
from ..core.resources import Resource
from . import model

log = logging.getLogger("sovd.http.streams")

TYPE_INFO_WAIT = 2.0   # seconds a frame's type_info fetch may take (in the background)


def topic_of(resource: Resource) -> tuple[str, str]:
    """``(topic, bytes mode)`` a ``data`` resource names (medkit's texts)."""
    data_id = unquote(resource.rest[1:])
    if not data_id.strip("/"):
        raise resource.invalid("Data collection requires a resource path (e.g. /api/v1/apps/{id}/data/{topic})")
    try:
        topic = normalize_topic(data_id)
    except InvalidTopic as exc:
        raise resource.invalid(str(exc)) from None
    mode = "array"
    for name, value in parse_qsl(resource.query, keep_blank_values=True):
        if name == "bytes":
            if value not in BYTES_MODES:
                raise resource.invalid("query parameter 'bytes' must be 'array' or 'base64'")
            mode = value
    return topic, mode


class TypeInfos:
    """A frame's ``x-medkit.type_info``: from the process's cache only; a miss is fetched in the background."""

    def __init__(self, ros: rosclient.RosClient):
        self.ros = ros
        self._fetching: set[str] = set()

    def cached(self, type_name: Any) -> bytes | None:
        if not isinstance(type_name, str):
            return None
        cached = self.ros.cached_type_info_json(type_name)
        if cached is None and type_name not in self._fetching:
            self._fetching.add(type_name)
            gevent.spawn(self._fetch, type_name)
        return cached or None

    def _fetch(self, type_name: str) -> None:
        try:
            self.ros.type_info(type_name, timeout=TYPE_INFO_WAIT)
        except IpcError as exc:
            log.info("type_info %s: %s", type_name, exc.message)
        finally:
            self._fetching.discard(type_name)

    def warm(self, stream: Any) -> None:
        """Before a stream's first frame (in its request's greenlet): its topic's type_info cached."""
        try:
            table = self.ros.entities().topics.get(stream.topic) or {}
            types = table.get("types")
            if isinstance(types, list) and types and isinstance(types[0], str):
                self.ros.type_info(types[0], timeout=self.ros.ipc_timeout)
        except IpcError as exc:
            log.info("type_info for %s: %s", stream.topic, exc.message)


def setup(app: Flask) -> None:
    infos = TypeInfos(app.extensions[rosclient.EXTENSION])

    def subscribed(resource: Resource, entity: Entity) -> dict[str, Any]:
        topic, mode = topic_of(resource)
        return {"topic": topic, "bytes": mode}

    def payload(stream: Any, meta: dict[str, Any], data: bytes) -> bytes:
        head, body, tail = model.body_parts(stream.topic, {**meta, "data_json": data}, stream.entity_id,
                                            infos.cached(meta.get("type")))
        return head + body + tail

    def error(stream: Any, exc: IpcError) -> bytes:
        return orjson.dumps(model.error(exc, stream.entity_id, stream.topic, stream.topic, 0).to_dict())

    resources.streamable(app, resources.Streamable("data", ("data",), subscribed, payload, error, infos.warm))
    resources.observable(app, resources.Observable(
        "data", lambda resource, entity, condition, path: topic_of(resource), "data"))
