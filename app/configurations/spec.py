"""The configurations family's part of the OpenAPI document: the nodes' ROS 2 parameters."""

from __future__ import annotations

from typing import Any

from ..core.entities import PARAM_NAMES
from ..openapi import build as oa

RESET_MEANS = ("ROS 2 has no default service: the gateway records each parameter's value the first time it "
               "reads the node (per node start: a restarted node is a new record); reset sets that value back. "
               "A parameter first seen after a change cannot be reset to an earlier value; with no record, 404.")
PARAM_VALUE = {"description": "bool, integer (int64), number (NaN and infinities as \"NaN\", \"Infinity\", "
                              "\"-Infinity\"), string, or an array of one of those; byte_array: integers 0-255"}
SCHEMAS: dict[str, Any] = {
    "ConfigurationMetaData": oa.obj(["id", "name", "type"], id={**oa.STR, "description": "the parameter's name; "
                                  "`<app_id>:<name>` on an entity of several nodes"}, name=oa.STR,
                                  type={"const": "parameter"}, **{"x-medkit": oa.OBJ}),
    "ConfigurationMetaDataList": oa.obj(["items"], items={"type": "array", "items": oa.ref("ConfigurationMetaData")},
                                      **{"x-medkit": {**oa.OBJ, "description": "entity_id, source, aggregation_level, "
                                         "is_aggregated, parameters (name, value, type of each, x-medkit source and "
                                         "node), source_ids, queried_nodes; partial with unavailable_nodes (503 "
                                         "class) and failed_nodes when some node did not answer"}}),
    "ConfigurationReadValue": oa.obj(["id", "data"], id=oa.STR, data=PARAM_VALUE, **{"x-medkit": {
        **oa.OBJ, "description": "ros2.node, entity_id, source, source_app (several nodes), parameter: name, value, "
                              "type (bool, int, double, string, byte_array, bool_array, int_array, double_array, "
                              "string_array) and, on a read, description, read_only, integer_range / "
                              "floating_point_range, additional_constraints, dynamic_typing"}}),
    "ConfigurationWriteValue": oa.obj(["data"], data=PARAM_VALUE),
    "ConfigurationDeleteMultiStatus": oa.obj(["entity_id", "results"], entity_id=oa.STR, results={
        "type": "array", "items": oa.obj(["node", "app_id", "success"], node=oa.STR, app_id=oa.STR,
                                       success={"type": "boolean"}, error=oa.STR,
                                       details={**oa.OBJ, "description": "reset: names set back; failed: name "
                                                                      "and the node's reason of each"})}),
}


def _configuration_paths(collection: str) -> dict[str, Any]:
    """medkit's configurations on apps, components and functions."""
    title, param = oa.schema_name(collection), PARAM_NAMES[collection]
    base = f"/{collection}/{{{param}}}/configurations"
    params = [oa.id_param(collection)]
    cfg_param = {"name": "config_id", "in": "path", "required": True, "schema": {**oa.STR, "maxLength": 512},
                 "description": "the parameter's name; `<app_id>:<name>` on an entity of several nodes"}
    token = {"security": [{"bearerAuth": []}, {}]}
    unavailable = ("503", "The node's parameter services are missing, gone, or did not answer within "
                          "parameter_service_timeout (`vendor-error`, `x-medkit-ros2-node-unavailable`; a node "
                          "that timed out is answered at once for parameter_negative_cache_s), or the ROS worker "
                          "is away; retry after `Retry-After` seconds")
    forbidden = ("403", "Changing configurations is off (`forbidden`: --allow-configurations), a wrong API token "
                        "(`forbidden`), or a read-only parameter (`vendor-error`, "
                        "`x-medkit-ros2-parameter-read-only`)")
    unauthorized = ("401", "An API token is configured and the request has none (`unauthorized`)")
    not_found = ("404", "Unknown entity (`entity-not-found`), parameter or source app (`resource-not-found`), or "
                        "no recorded default (reset)")
    bad = ("400", "A value of the wrong type or out of range, with the node's own reason in `details` "
                  "(`invalid-parameter`), an id too long, a body without `data`, or a bare id on an entity of "
                  "several nodes (`invalid-request`)")
    write = oa.op(f"set{title}Configuration", "Configuration", "Set one ROS 2 parameter; answers the value as the "
                "node now reports it", oa.ok("ConfigurationReadValue"), bad, unauthorized, forbidden, not_found,
                *oa.BODY_ERRORS, unavailable, "504", **token, parameters=params + [cfg_param],
                requestBody={"required": True, "content": {"application/json": {
                    "schema": oa.ref("ConfigurationWriteValue")}}})
    reset_one = oa.op(f"delete{title}Configuration", "Configuration", "Reset one parameter to its default. "
                    + RESET_MEANS, None, bad, unauthorized, forbidden, not_found, unavailable, "504", **token,
                    parameters=params + [cfg_param])
    reset_one["responses"] = {"204": {"description": "Reset"}, **reset_one["responses"]}
    reset_all = oa.op(f"deleteAll{title}Configurations", "Configuration", "Reset every parameter of the entity's "
                    "nodes to its default. " + RESET_MEANS, None, unauthorized, forbidden, ("404", oa.ERRORS["404"]),
                    "503", "504", **token, parameters=params)
    reset_all["responses"] = {"204": {"description": "All reset"},
                              "207": oa.ok("ConfigurationDeleteMultiStatus", "Some parameters were not reset: "
                                         "each node's entry names them and the node's reason"),
                              **reset_all["responses"]}
    return {
        base: {
            "get": oa.op(f"list{title}Configurations", "Configuration", f"The ROS 2 parameters of a "
                       f"{collection[:-1]}'s nodes; a node that does not answer makes the list partial",
                       oa.ok("ConfigurationMetaDataList"), "400", "404", unavailable, "504", parameters=params),
            "delete": reset_all,
        },
        base + "/{config_id}": {
            "get": oa.op(f"get{title}Configuration", "Configuration", "One parameter: value, type, description, "
                       "read-only, ranges", oa.ok("ConfigurationReadValue"), bad, not_found, unavailable, "504",
                       parameters=params + [cfg_param]),
            "put": write,
            "delete": reset_one,
        },
    }


SPEC = oa.Spec(paths=lambda: {k: v for c in oa.RESOURCE_COLLECTIONS for k, v in _configuration_paths(c).items()},
            schemas=SCHEMAS, tags=({"name": "Configuration", "description": "ROS 2 parameters of the nodes "
                                                                           "(configurations)"},))
