"""The bulk-data routes' part of the OpenAPI document (its ``FAMILY.spec``,
``app/openapi/``): medkit's operationIds (``ros2_medkit_clients``), its schema names
(``BulkDataCategoryList``, ``BulkDataDescriptor``, ``BulkDataDescriptorList``) and tag (``Bulk Data``)."""

from __future__ import annotations

from typing import Any

from ipc import counters

from ..openapi.build import (
    BODY_ERRORS,
    INT,
    STR,
    Spec,
    counter_props,
    error,
    id_param,
    obj,
    ok,
    op,
    ref,
)
from ..openapi.build import schema_name as title

TAG = "Bulk Data"
TAG_DESCRIPTION = ("Fault recordings (MCAP, the `rosbags` category) and uploaded files (`bulk_data_categories`); "
                   "issue 32")
COLLECTIONS = ("areas", "components", "apps", "functions")
WRITABLE = ("apps", "components")
NESTED = {"areas": ("subareas", "subarea_id", "Subarea"), "components": ("subcomponents", "subcomponent_id",
                                                                        "Subcomponent")}
_RANGE_HEADERS = {
    "Content-Disposition": "`attachment; filename=\"<recording id>.mcap\"` or the uploaded file's name",
    "Content-Length": "bytes of the body (the range's with a 206)",
    "Accept-Ranges": "`bytes`", "ETag": "the file's version: send it back in `If-Range` to resume",
    "Content-Range": "206 only: `bytes <first>-<last>/<size>`",
}


def schemas() -> dict[str, Any]:

    descriptor = obj(
        ["id", "name", "mimetype", "size", "creation_date"],
        id={**STR, "description": "a recording's id (`fault_<CODE>_<ms>`) or an upload's "
                                  "(`<category>_<ns>_<hex>`): what the download URL takes"},
        name=STR, mimetype={**STR, "description": "`application/x-mcap` for a recording"},
        size={**INT, "description": "bytes"}, creation_date={**STR, "format": "date-time"},
        description={**STR, "description": "an upload's, when given"},
        X_medkit={"type": "object", "additionalProperties": True,
                  "description": "a recording: `fault_codes`, `duration_sec`, `format`, `recording_id`, "
                                 "`topics`, `messages`; an upload: the `metadata` given with it"})
    return {
        "BulkDataCategoryList": obj(["items"], items={"type": "array", "items": STR,
                                                      "description": "`rosbags`, then bulk_data_categories"}),
        "BulkDataDescriptor": descriptor,
        "BulkDataDescriptorList": obj(["items"], items={"type": "array", "items": ref("BulkDataDescriptor")}),
        "BulkDataUpload": obj(["file"], file={**STR, "format": "binary"},
                              description={**STR, "maxLength": 65536},
                              metadata={**STR, "description": "a JSON object, as text: the descriptor's x-medkit"}),
    }


HEALTH_DESCRIPTION = ("fault recordings (rosworker/bulk_data/): the ring buffer, the recordings written and on "
                      "disk, write errors; zeros before the ROS worker first answers")


def health_schema() -> dict[str, Any]:

    return {**obj(list(counters.health_keys("bulk_data")), **counter_props("bulk_data")),
            "description": HEALTH_DESCRIPTION}


def paths() -> dict[str, Any]:
    """``{path: {method: operation}}`` of every bulk-data route."""

    category = {"name": "category_id", "in": "path", "required": True, "schema": STR,
                "description": "`rosbags` or one of bulk_data_categories"}
    file_id = {"name": "file_id", "in": "path", "required": True, "schema": STR,
               "description": "a descriptor's id; for `rosbags` also a fault code (its newest recording)"}
    bad = ("400", "Invalid entity ID, or a category or id that is not a plain name (`..`, `/`: "
                  "`invalid-parameter`)")
    not_found = ("404", "Unknown entity (`entity-not-found`), category (`resource-not-found`, `Unknown "
                        "category`) or file (`resource-not-found`, `Bulk-data not found`): a recording none of "
                        "whose faults belongs to the entity is not found there")
    download_ok = {"description": "The whole file",
                   "headers": {k: {"schema": STR, "description": v} for k, v in _RANGE_HEADERS.items()},
                   "content": {"application/octet-stream": {"schema": {
                       **STR, "format": "binary", "description": "the file's bytes; Content-Type says its type: "
                       "application/x-mcap for a recording, an upload's own"}}}}
    token = {"security": [{"bearerAuth": []}, {}]}
    write_errors = (
        ("400", "Invalid entity ID; `rosbags` (read-only), an unknown category or a bad id (`invalid-parameter`); "
                "a body without a `file` part, or a malformed multipart body (`invalid-request`)"),
        ("401", "An API token is configured and the request has none (`unauthorized`)"),
        ("403", "Uploading and deleting bulk data is off (`forbidden`: --allow-bulk-data not given), or the "
                "API token is wrong (`forbidden`)"))
    out: dict[str, Any] = {}
    for collection in COLLECTIONS:
        name = title(collection)
        base = f"/{collection}/{{{id_param(collection)['name']}}}/bulk-data"
        params = [id_param(collection)]
        out[base] = {"get": op(f"list{name}BulkDataCategories", TAG, "Bulk-data categories",
                               ok("BulkDataCategoryList"), bad, "404", parameters=params)}
        out[base + "/{category_id}"] = {"get": op(
            f"list{name}BulkDataDescriptors", TAG, "The files of a category (recordings: those of the entity's "
            "faults)", ok("BulkDataDescriptorList"), bad, not_found, "503", "504", parameters=params + [category])}
        download = op(f"download{name}BulkData", TAG, "Download a file (streamed; Range resumes it)", download_ok,
                      bad, not_found, ("416", "A range past the end of the file (`invalid-request`, header "
                                              "`Content-Range: bytes */<size>`)"), "503", "504",
                      parameters=params + [category, file_id,
                                           {"name": "Range", "in": "header", "required": False, "schema": STR,
                                            "description": "`bytes=<first>-[<last>]` or `bytes=-<n>`"},
                                           {"name": "If-Range", "in": "header", "required": False,
                                            "schema": STR, "description": "the ETag it had"}])
        download["responses"] = {"200": download_ok, "206": {**download_ok, "description": "The range asked "
                                                                  "(`Content-Range`)"}, **download["responses"]}
        out[base + "/{category_id}/{file_id}"] = {"get": download}
        if collection in WRITABLE:
            upload = op(f"upload{name}BulkData", TAG, "Upload a file (multipart/form-data: file, description, "
                        "metadata; a write: allow_bulk_data and the token)", None, *write_errors, "404",
                        *BODY_ERRORS, ("507", "The storage is full: bulk_data_max_total_mb, or the disk "
                                              "(`vendor-error`, `x-medkit-insufficient-storage`)"),
                        **token, parameters=params + [category],
                        requestBody={"required": True, "content": {"multipart/form-data": {
                            "schema": {"$ref": "#/components/schemas/BulkDataUpload"}}}})
            upload["responses"] = {"201": {**ok("BulkDataDescriptor", "Stored"), "headers": {
                "Location": {"schema": STR, "description": "the file's URL"}}}, **upload["responses"]}
            upload["responses"]["413"] = error("The file is larger than bulk_data_max_upload_size "
                                               "(`payload-too-large`, parameters `max_upload_size`)")
            delete = op(f"delete{name}BulkData", TAG, "Delete an uploaded file (a write)", None, *write_errors,
                        not_found, **token, parameters=params + [category, file_id])
            delete["responses"] = {"204": {"description": "Deleted"}, **delete["responses"]}
            out[base + "/{category_id}"]["post"] = upload
            out[base + "/{category_id}/{file_id}"]["delete"] = delete
        if collection in NESTED:
            relation, param, kind = NESTED[collection]
            nested = f"/{collection}/{{{id_param(collection)['name']}}}/{relation}/{{{param}}}/bulk-data"
            sub = {"name": param, "in": "path", "required": True, "schema": STR}
            gone = ("404", f"Unknown {collection[:-1]} or {kind.lower()} (`entity-not-found`): runtime discovery "
                           f"knows no {relation}")
            out[nested] = {"get": op(f"list{kind}BulkDataCategories", TAG, f"Bulk-data categories of a "
                                     f"{kind.lower()}", ok("BulkDataCategoryList"), "400", gone,
                                     parameters=params + [sub])}
            out[nested + "/{category_id}"] = {"get": op(
                f"list{kind}BulkDataDescriptors", TAG, f"The files of a {kind.lower()}'s category",
                ok("BulkDataDescriptorList"), "400", gone, parameters=params + [sub, category])}
            out[nested + "/{category_id}/{file_id}"] = {"get": op(
                f"download{kind}BulkData", TAG, f"Download a {kind.lower()}'s file", download_ok, "400", gone,
                parameters=params + [sub, category, file_id])}
    return out


SPEC = Spec(paths=paths, schemas=schemas(), tags=({"name": TAG, "description": TAG_DESCRIPTION},))
