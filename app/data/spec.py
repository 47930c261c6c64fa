"""The data family's part of the OpenAPI document: data items, samples, publishing."""

from __future__ import annotations

from typing import Any

from ..core.entities import COLLECTIONS, PARAM_NAMES
from ..openapi import build as oa

SCHEMAS: dict[str, Any] = {
    "DataItem": oa.obj(
        ["id", "name", "category", "x-medkit"], id=oa.STR, name=oa.STR, category={"const": "currentData"},
        X_medkit=oa.obj(
            ["ros2"],
            ros2=oa.obj(["topic", "direction"], topic=oa.STR, type=oa.STR,
                      direction={"enum": ["publish", "subscribe", "both"]}),
            type_info={**oa.obj(["schema", "default_value"], schema=oa.OBJ, default_value=oa.OBJ),
                       "description": "only when the message type is installed"},
            member_ids={**oa.STR_LIST, "description": "components and functions: apps using the topic"},
        ),
    ),
    "DataList": oa.obj(
        ["items", "x-medkit"], items={"type": "array", "items": oa.ref("DataItem")},
        X_medkit=oa.obj(["entity_id", "total_count"], entity_id=oa.ENTITY_ID, total_count=oa.INT,
                      aggregated={"type": "boolean", "enum": [True]}, aggregation_sources=oa.STR_LIST,
                      aggregation_level={"enum": ["component", "function", "area"]}),
    ),
    "DataValue": oa.obj(
        ["id", "data", "x-medkit"], id=oa.STR,
        data={**oa.OBJ, "description": "the message, fields with their ROS names and real types; "
                                    "{} without data.  A float that is NaN or +-inf is the string "
                                    '"NaN", "Infinity" or "-Infinity" (as in the proto3 JSON mapping); '
                                    "the type's schema in the data listing says so"},
        X_medkit=oa.obj(
            ["entity_id", "timestamp", "ros2", "publisher_count", "subscriber_count", "status"],
            entity_id=oa.ENTITY_ID,
            timestamp={**oa.INT, "description": "ns since the epoch when the gateway received it (now without data)"},
            ros2=oa.obj(["topic"], topic=oa.STR,
                      type={**oa.STR, "description": "from the graph: the publishers' type, or the "
                                                  "subscribers' on a topic without publishers"}),
            publisher_count=oa.INT, subscriber_count=oa.INT,
            status={"enum": ["data", "metadata_only"]},
            type_info={**oa.obj(["schema", "default_value"], schema=oa.OBJ, default_value=oa.OBJ),
                       "description": "as in the data listing; only when the type is known and installed"},
            reason={"enum": ["not-in-graph", "no-publishers", "timeout", "unsupported-type",
                             "evicted", "shutdown"], "description": "only with metadata_only"},
        ),
    ),
    "DataWriteRequest": oa.obj(["type", "data"],
                           type={"type": "string", "pattern": "^[A-Za-z][A-Za-z0-9_]*/msg/[A-Za-z][A-Za-z0-9_]*$",
                                 "examples": ["std_msgs/msg/Float32"]},
                           data={**oa.OBJ, "examples": [{"data": 50.0}, {"range_max": "Infinity"}],
                                 "description": "the message's fields (left out: default).  Float fields "
                                                'take a number, "NaN", "Infinity" or "-Infinity"; null '
                                                "is read as NaN"}),
    "DataWriteResult": oa.obj(
        ["id", "data", "x-medkit"], id=oa.STR, data=oa.OBJ,
        X_medkit=oa.obj(["ros2", "entity_id", "status", "subscriber_count", "unmatched_subscriber_count"],
                      ros2=oa.obj(["topic", "type"], topic=oa.STR, type=oa.STR),
                      entity_id=oa.ENTITY_ID, status={"const": "published"},
                      subscriber_count={**oa.INT, "description": "subscriptions the message went to"},
                      unmatched_subscriber_count={**oa.INT, "description": "subscribers in the graph it did not "
                                                  "reach (another QoS or message-type version)"},
                      warning={**oa.STR, "description": "only when unmatched_subscriber_count > 0"}),
    ),
    "DataCategoryList": oa.obj(["items"], items={"type": "array", "items": oa.OBJ}),
    "DataGroupList": oa.obj(["items"], items={"type": "array", "items": oa.OBJ}),
}
HEALTH_SCHEMA = oa.counters_schema("data_provider", "the topic pool: x-medkit-data-provider", {
    "evictions": {"type": "object", "additionalProperties": oa.INT,
                  "description": "evictions_total by cause (graph, type_change, lru, idle, qos_rebuild, "
                                 "manual, shutdown, bytes); empty until the ROS worker first answers"}})
HEALTH_SCHEMA["required"].append("evictions")


def _paths(collection: str) -> dict[str, Any]:
    """medkit's data routes of an entity: the data items, one sample, publishing one message."""
    name = PARAM_NAMES[collection]
    kind = collection[:-1]
    name_ = oa.schema_name(collection)
    base = f"/{collection}/{{{name}}}"
    entity = oa.id_param(collection)
    data_param = {"name": "data_id", "in": "path", "required": True, "schema": oa.STR,
                  "description": ("ROS topic. May span several path segments and be percent-encoded: "
                                  "`powertrain%2Fengine%2Ftemperature`, `powertrain/engine/temperature` "
                                  "and `/powertrain/engine/temperature` (written `data//powertrain/...`) "
                                  "all name `/powertrain/engine/temperature`. A topic `/docs` is read as "
                                  "`data//docs`: `data/docs` is the scoped OpenAPI document.")}
    bytes_param = {"name": "bytes", "in": "query", "required": False,
                   "schema": {"enum": ["array", "base64"], "default": "array"},
                   "description": "how byte and uint8 arrays are sent: arrays of integers (default) "
                                  "or base64 strings"}
    not_impl = ("501", "Not implemented for ROS 2 (`not-implemented`)")
    put_op = oa.op(f"put{name_}DataItem", "Data", f"Publish one message to a topic through a {kind}",
                 oa.ok("DataWriteResult", "Published"),
                 ("400", oa.ERRORS["400"] + "; a message type the topic's publishers and subscribers do not "
                         "use (`invalid-parameter`, parameters `topic`, `type`, `topic_types`: nothing is "
                         "published or created).  The entity is checked before the body, as medkit does"),
                 ("401", "An API token is configured and the request has none (`unauthorized`)"),
                 ("403", "Publishing is disabled (`--allow-publish` not given) or the token is wrong "
                         "(`forbidden`)"),
                 "404", *oa.BODY_ERRORS, "500", "503", "504",
                 parameters=[entity, data_param],
                 requestBody={"required": True,
                              "content": {"application/json": {"schema": oa.ref("DataWriteRequest")}}},
                 security=[{"bearerAuth": []}, {}])
    return {
        base + "/data": {"get": oa.op(f"list{name_}Data", "Data", f"Data items of a {kind} (metadata only)",
                                    oa.ok("DataList"), "400", "404", "503", "504", parameters=[entity])},
        base + "/data/{data_id}": {
            "get": oa.op(f"get{name_}DataItem", "Data", f"Read one sample of a topic through a {kind}",
                       oa.ok("DataValue"), "400", "404", "502", "503", "504",
                       parameters=[entity, data_param, bytes_param]),
            "put": put_op,
        },
        base + "/data-categories": {"get": oa.op(f"list{name_}DataCategories", "Data", "Data categories",
                                               oa.ok("DataCategoryList", "medkit's answer; never sent by this "
                                                   "gateway, which answers 501"), not_impl,
                                               parameters=[entity])},
        base + "/data-groups": {"get": oa.op(f"list{name_}DataGroups", "Data", "Data groups",
                                           oa.ok("DataGroupList", "medkit's answer; never sent by this "
                                               "gateway, which answers 501"), not_impl,
                                           parameters=[entity])},
    }


SPEC = oa.Spec(paths=lambda: {k: v for c in COLLECTIONS for k, v in _paths(c).items()}, schemas=SCHEMAS,
            tags=({"name": "Data", "description": "Read and write ROS 2 topic data"},))
