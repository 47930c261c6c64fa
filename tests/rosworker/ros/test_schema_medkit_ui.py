"""medkit's web UI, as a real client of our ``type_info`` schemas: which input its forms draw for each field.

The web UI (github.com/selfpatch/ros2_medkit_web_ui, at 5c82910) turns a data item's or an
operation's JSON schema into a form: ``convertJsonSchemaToTopicSchema`` (src/lib/schema-utils.ts)
maps each property's ``type``, then ``SchemaFormField`` (src/components/SchemaFormField.tsx) draws
an array editor, a nested object, a checkbox, a number field, a text field, or, for anything else, a
raw JSON input.  Below is that decision, ported line by line (JavaScript's semantics kept: a
``switch`` compares with ``===``, ``!type`` is any falsy value, and ``type.toLowerCase()`` on a
non-string throws a TypeError, which breaks the whole form).  It was checked against the UI's own
code, run with node over the same schemas: the same answer for each field, the same TypeError for a
list of types.
"""

from __future__ import annotations

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from sensor_msgs.msg import BatteryState, Image, LaserScan, Temperature
from std_msgs.msg import Bool, Float32, Float64MultiArray, String
from test_msgs.action import Fibonacci

from rosworker.ros.schema import schema

# ---- src/lib/schema-utils.ts ----------------------------------------------------------------------
PRIMITIVES = ("bool", "boolean", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
              "float", "float32", "float64", "double", "string", "wstring", "byte", "char")
NUMERICS = ("int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "float", "float32",
            "float64", "double", "byte")


def _lower(type_):
    if not isinstance(type_, str):
        raise TypeError("type.toLowerCase is not a function")
    return type_.lower()


def map_json_schema_type(type_):
    if not type_:
        return "object"
    return {"integer": "int32", "number": "float64", "boolean": "bool", "string": "string", "array": "array",
            "object": "object"}.get(type_, type_) if isinstance(type_, str) else type_


def convert_field(field: dict) -> dict:
    result = {"type": map_json_schema_type(field.get("type"))}
    if field.get("properties"):
        result["fields"] = {k: convert_field(v) for k, v in field["properties"].items()}
    if field.get("items"):
        result["items"] = convert_field(field["items"])
    return result


def convert_json_schema_to_topic_schema(json_schema: dict) -> dict:
    if json_schema.get("properties"):
        return {k: convert_field(v) for k, v in json_schema["properties"].items()}
    return json_schema


def is_primitive_type(type_) -> bool:
    return _lower(type_) in PRIMITIVES


def is_numeric_type(type_) -> bool:
    return _lower(type_) in NUMERICS


def is_boolean_type(type_) -> bool:
    return _lower(type_) in ("bool", "boolean")


def get_default_value(field: dict):
    if field["type"] == "array":
        return []
    if field.get("fields"):
        return {k: get_default_value(v) for k, v in field["fields"].items()}
    if is_numeric_type(field["type"]):
        return 0
    if is_boolean_type(field["type"]):
        return False
    return ""


# ---- src/components/SchemaFormField.tsx: the input drawn for one field -----------------------------
def widget(field: dict) -> str:
    if field["type"] == "array" and field.get("items"):
        return "array of " + widget(field["items"])
    if field.get("fields"):
        return "object"
    if is_primitive_type(field["type"]):
        if is_boolean_type(field["type"]):
            return "checkbox"
        if is_numeric_type(field["type"]):
            return f"number ({field['type']})"
        return "text"
    return "JSON input"


def form(json_schema: dict) -> dict:
    """Every field of the form medkit's UI draws for ``json_schema``, by dotted path (getSchemaDefaults too)."""
    out = {}

    def walk(prefix: str, fields: dict) -> None:
        for name, field in fields.items():
            get_default_value(field)
            out[prefix + name] = widget(field)
            if field.get("fields"):
                walk(prefix + name + ".", field["fields"])

    walk("", convert_json_schema_to_topic_schema(json_schema))
    return out


# ---- our schemas through it ------------------------------------------------------------------------
def test_floats_are_number_fields_in_medkits_forms():
    assert form(schema(Temperature)) == {
        "header": "object", "header.stamp": "object", "header.stamp.sec": "number (int32)",
        "header.stamp.nanosec": "number (int32)", "header.frame_id": "text",
        "temperature": "number (float64)", "variance": "number (float64)"}
    assert form(schema(Float32)) == {"data": "number (float64)"}
    scan = form(schema(LaserScan))
    assert scan["range_max"] == "number (float64)" and scan["ranges"] == "array of number (float64)"
    assert form(schema(Float64MultiArray))["data"] == "array of number (float64)"
    assert form(schema(Odometry))["pose.covariance"] == "array of number (float64)"
    goal = form(schema(Fibonacci.Goal))
    assert goal == {"order": "number (int32)"}


@pytest.mark.parametrize("cls", [Temperature, LaserScan, Odometry, BatteryState, Image, DiagnosticArray,
                                 Bool, String, Float64MultiArray, Fibonacci.Feedback])
def test_no_field_of_ours_falls_back_to_a_raw_json_input(cls):
    for mode in ("array", "base64"):
        drawn = form(schema(cls, mode))
        assert drawn and not [k for k, w in drawn.items() if "JSON input" in w], drawn


def test_the_port_draws_what_the_ui_draws_for_the_other_shapes():
    """The shapes a float's schema could take: without a type (ours before) the UI falls back to a raw JSON
    input; with a list of types (the JSON Schema way to say "number or string") its form builder throws."""
    non_finite = {"anyOf": [{"type": "number"}, {"type": "string", "enum": ["NaN", "Infinity", "-Infinity"]}]}
    assert form({"properties": {"x": non_finite}}) == {"x": "JSON input"}
    with pytest.raises(TypeError, match="toLowerCase"):
        form({"properties": {"x": {"type": ["number", "string"], **non_finite}}})
    assert form({"properties": {"x": {"type": "number", **non_finite}}}) == {"x": "number (float64)"}
    assert form({"properties": {"b": {"type": "boolean"}, "s": {"type": "string"}}}) == {"b": "checkbox", "s": "text"}
