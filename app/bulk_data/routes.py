"""medkit's bulk-data routes: ``/{entity}/bulk-data[/{category}[/{id}]]``.

- ``GET .../bulk-data``: the categories, ``rosbags`` first, then ``bulk_data_categories``.
- ``GET .../bulk-data/{category}``: the items (medkit's ``BulkDataDescriptor``: id, name,
  mimetype, size, creation_date, x-medkit).
- ``GET .../bulk-data/{category}/{id}``: the file, streamed (``download.py``: Range,
  Content-Disposition, Content-Length).
- ``POST .../bulk-data/{category}`` (apps and components): a multipart upload
  (``files.py``), 201 with its descriptor and ``Location``.
- ``DELETE .../bulk-data/{category}/{id}`` (apps and components): 204.

``rosbags`` holds the fault recordings (the ROS worker's, ``rosworker/bulk_data/``): read-only
(POST and DELETE answer 400 as in medkit) and scoped like faults: an entity sees a
recording when one of its faults belongs to the entity (medkit's all-sources rule,
``app/faults/routes.py``: every reporting source is one of the entity's nodes).  A
recording's download URL takes its id (``fault_<CODE>_<ms>``) or, as medkit's older
URLs, a fault code (that fault's newest recording, when that fault is in scope).  The
ROS worker tells where the file is; the HTTP worker reads it.

Upload and delete are writes: ``allow_bulk_data`` and the API token (403/401), checked
before the entity or the body.  An unknown category answers 404 on a read and 400 on a
write (medkit's); a category or an id that could leave its directory (``..``, ``/``, a
control character) answers 400 ``invalid-parameter``.  Subareas and subcomponents have
the routes too; runtime discovery knows none, so they answer 404.
"""

from __future__ import annotations

from typing import Any

from flask import Blueprint, current_app, request
from werkzeug.exceptions import HTTPException
from werkzeug.routing import BaseConverter

from common import settings
from ipc.errors import IpcError

from ..core import rosclient
from ..core.auth import authorize_feature
from ..core.common import config, in_scope, json_response, lookup, member_nodes
from ..core.entities import API_BASE, PARAM_NAMES, Entity
from ..core.errors import ApiError
from ..sse.stream import rfc3339
from . import download, files

bp = Blueprint("bulk_data", __name__, url_prefix=API_BASE)

ROSBAGS = settings.ROSBAGS
MCAP_TYPE = "application/x-mcap"
ALL_STATUSES = ["PREFAILED", "CONFIRMED", "PREPASSED", "HEALED", "CLEARED"]
ENTITY = "/<collection:collection>/<entity_id>"
WRITABLE = "/<any(apps, components):collection>/<entity_id>"
SUB = {"areas": "subareas", "components": "subcomponents"}


class RestConverter(BaseConverter):
    """Everything after ``bulk-data/``: ``{category}`` or ``{category}/{id}``, checked by the views (an id
    with ``../`` is a 400 of the contract, not a route that does not match)."""

    regex = r"[\s\S]+"
    part_isolating = False


def store() -> files.FileStore:
    cfg = config()
    return files.FileStore(settings.bulk_data_dir(cfg), settings.names(cfg.bulk_data_categories),
                           cfg.bulk_data_max_upload_size, cfg.bulk_data_max_total_mb * 2**20)


def _categories() -> list[str]:
    return [ROSBAGS, *settings.names(config().bulk_data_categories)]


def _split(rest: str, write: bool) -> tuple[str, str | None]:
    """``(category, id or None)``: 400 for names that could leave their directory, 404 (400 on a write)
    for a category the gateway does not have."""
    category, sep, item_id = rest.partition("/")
    files.check_id(category, "bulk-data category")
    if sep:
        files.check_id(item_id)
    if category not in _categories():
        if write:
            raise ApiError(400, "invalid-parameter", f"Unknown bulk-data category: {category}",
                           {"category": category, "allowed": _categories()})
        raise ApiError(404, "resource-not-found", f"Unknown category: {category}", {"category": category})
    return category, (item_id if sep else None)


def _call(cmd: str, args: dict[str, Any]) -> dict[str, Any]:
    try:
        return rosclient.get().call(cmd, args, config().ipc_timeout)
    except IpcError as exc:
        raise ApiError.from_ipc(exc) from None


# ---- rosbags: the fault recordings ---------------------------------------------------------------------
def _fault_sources() -> dict[str, list[str]]:
    """Every fault's reporting sources now (a fault's sources may have been named better since it was
    recorded)."""
    items = _call("fault_list", {"statuses": ALL_STATUSES}).get("items") or []
    return {f["fault_code"]: f.get("reporting_sources") or [] for f in items if isinstance(f, dict)}


def _owned(recording: dict[str, Any], codes: list[str], fqns: list[str], current: dict[str, list[str]]) -> bool:
    recorded = recording.get("sources") or {}
    return any(in_scope({"reporting_sources": current.get(c) or recorded.get(c) or []}, fqns) for c in codes)


def _fqns(entity: Entity) -> list[str]:
    return sorted({fqn for _, fqn in member_nodes(entity) if fqn})


def rosbag_descriptor(recording: dict[str, Any]) -> dict[str, Any]:
    """medkit's descriptor of a recording (``fold_rosbag_rows_into_descriptors``)."""
    created = rfc3339(recording["created_ns"]).decode()
    return {"id": recording["id"], "name": f"{recording['id']} recording {created}", "mimetype": MCAP_TYPE,
            "size": recording["size"], "creation_date": created,
            "x-medkit": {"fault_codes": sorted(recording["fault_codes"]), "duration_sec": recording["duration_sec"],
                         "format": recording["format"], "recording_id": recording["id"],
                         "topics": [t["topic"] for t in recording["topics"]], "messages": recording["messages"]}}


def _rosbags(entity: Entity) -> list[dict[str, Any]]:
    recordings = _call("bulk_rosbags", {}).get("items") or []
    if not recordings:
        return []
    fqns, current = _fqns(entity), _fault_sources()
    return [rosbag_descriptor(r) for r in recordings if _owned(r, r["fault_codes"], fqns, current)]


def _rosbag_download(entity: Entity, item_id: str):
    params = {"bulk_data_id": item_id}
    not_found = ApiError(404, "resource-not-found", "Bulk-data not found", params)
    try:
        recording = rosclient.get().call("bulk_rosbag_get", {"id": item_id}, config().ipc_timeout)
    except IpcError as exc:
        if exc.code == "no-such-recording":
            raise not_found from None
        raise ApiError.from_ipc(exc, params) from None
    # By its id: any of its faults in scope (a burst shares one recording). By a fault code (medkit's
    # older URLs): that fault must be in scope, not only some fault the recording is shared with.
    codes = [item_id] if recording.get("by_fault_code") else recording["fault_codes"]
    if not _owned(recording, codes, _fqns(entity), _fault_sources()):
        raise ApiError(404, "resource-not-found", "Bulk-data not found for this entity",
                       {"entity_id": entity.id, **params})
    return download.file_response(recording["path"], recording["id"] + ".mcap", MCAP_TYPE, not_found)


# ---- the routes ------------------------------------------------------------------------------------------
@bp.get(ENTITY + "/bulk-data")
def categories(collection: str, entity_id: str):
    lookup(collection, entity_id)
    return json_response({"items": _categories()})


@bp.get(ENTITY + "/bulk-data/<bulk_rest:rest>")
def read(collection: str, entity_id: str, rest: str):
    entity = lookup(collection, entity_id)
    category, item_id = _split(rest, write=False)
    if item_id is None:
        if category == ROSBAGS:
            return json_response({"items": _rosbags(entity)})
        items = store().items(collection, entity.id, category)
        return json_response({"items": [files.public(d) for d in items]})
    if category == ROSBAGS:
        return _rosbag_download(entity, item_id)
    found = store().find(collection, entity.id, category, item_id)
    not_found = ApiError(404, "resource-not-found", "Bulk-data not found", {"bulk_data_id": item_id})
    if found is None:
        raise not_found
    desc, path = found
    return download.file_response(path, desc["name"], desc["mime_type"], not_found)


def _authorize() -> None:
    authorize_feature(config().allow_bulk_data, "Uploading and deleting bulk data", "--allow-bulk-data",
                      "enable POST and DELETE on .../bulk-data")


def _writable(category: str) -> None:
    if category == ROSBAGS:
        raise ApiError(400, "invalid-parameter", f"Category '{ROSBAGS}' does not support "
                       f"{'upload' if request.method == 'POST' else 'deletion'}. Rosbags are managed by the "
                       "fault system.", {"category": ROSBAGS})


@bp.post(WRITABLE + "/bulk-data/<bulk_rest:rest>")
def upload(collection: str, entity_id: str, rest: str):
    _authorize()
    entity = lookup(collection, entity_id)
    category, item_id = _split(rest, write=True)
    if item_id is not None:
        raise ApiError(405, "invalid-request", "Method not allowed", {"method": "POST", "allowed_methods":
                                                                       ["DELETE", "GET", "HEAD", "OPTIONS"]},
                       headers={"Allow": "DELETE, GET, HEAD, OPTIONS"})
    _writable(category)
    boundary = files.boundary_of(request.headers.get("Content-Type"))
    target = store()
    length = request.content_length
    if length is not None and length > target.max_upload + files.MULTIPART_SLACK:
        raise ApiError(413, "payload-too-large", "File size exceeds maximum upload limit",
                       {"max_upload_size": target.max_upload})
    if length is not None and files.blocking(target.usage) + length - files.MULTIPART_SLACK > target.max_total:
        raise files.storage_full(target.max_total)
    request.max_content_length = target.max_upload + files.MULTIPART_SLACK
    desc = target.upload(collection, entity.id, category, _Body(request.stream), boundary)
    location = f"{API_BASE}/{collection}/{entity.id}/bulk-data/{category}/{desc['id']}"
    return json_response(files.public(desc), 201, headers={"Location": location})


class _Body:
    """The request's body stream, its framing errors as the contract's 400 (``app/core/bodies.py``'s)."""

    def __init__(self, stream):
        self.stream = stream

    def read(self, size: int) -> bytes:
        try:
            return self.stream.read(size)
        except HTTPException:  # 413 past the limit, the body deadline's 408
            raise
        except Exception as exc:  # gunicorn's NoMoreData, InvalidChunkSize ...
            raise ApiError(400, "invalid-request", "Request body could not be read",
                           {"details": f"malformed request body ({type(exc).__name__})"}) from None


@bp.delete(WRITABLE + "/bulk-data/<bulk_rest:rest>")
def delete(collection: str, entity_id: str, rest: str):
    _authorize()
    entity = lookup(collection, entity_id)
    category, item_id = _split(rest, write=True)
    _writable(category)
    if item_id is None:
        raise ApiError(405, "invalid-request", "Method not allowed", {"method": "DELETE", "allowed_methods":
                                                                         ["GET", "HEAD", "OPTIONS", "POST"]},
                       headers={"Allow": "GET, HEAD, OPTIONS, POST"})
    if not store().delete(collection, entity.id, category, item_id):
        raise ApiError(404, "resource-not-found", "Bulk-data item not found", {"bulk_data_id": item_id})
    return current_app.response_class(status=204)


@bp.get("/<any(areas, components):collection>/<entity_id>/<any(subareas, subcomponents):relation>/<sub_id>"
        "/bulk-data", defaults={"rest": None})
@bp.get("/<any(areas, components):collection>/<entity_id>/<any(subareas, subcomponents):relation>/<sub_id>"
        "/bulk-data/<bulk_rest:rest>")
def nested(collection: str, entity_id: str, relation: str, sub_id: str, rest: str | None):
    """A subarea's or subcomponent's bulk data: runtime discovery knows none, so 404 after the parent's checks."""
    lookup(collection, entity_id)
    if SUB[collection] != relation:
        raise ApiError(404, "resource-not-found", "Resource not found", {"status": 404, "path": request.path})
    kind = "Subarea" if collection == "areas" else "Subcomponent"
    raise ApiError(404, "entity-not-found", f"{kind} not found", {PARAM_NAMES[collection]: entity_id,
                                                                    f"{kind.lower()}_id": sub_id})
