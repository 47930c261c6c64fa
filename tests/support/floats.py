"""Validating samples against the gateway's schemas, whose floats may be "NaN", "Infinity", "-Infinity".

A float's schema is ``{"type": "number", "anyOf": [{"type": "number"}, {"type": "string", "enum":
["NaN", "Infinity", "-Infinity"]}]}`` (rosworker/ros/schema.py): ``type`` as medkit's, for the form
builders that read it, and the anyOf for the strings a non-finite float is written as.  A stock
JSON Schema validator applies ``type`` first and refuses those strings; :func:`validate` is one whose
``number`` also takes them, as the README tells a client to do.
"""

from __future__ import annotations

NON_FINITE = ("NaN", "Infinity", "-Infinity")


def validator_class():
    import jsonschema

    base = jsonschema.Draft202012Validator
    checker = base.TYPE_CHECKER.redefine(
        "number", lambda checker, value: base.TYPE_CHECKER.is_type(value, "number") or value in NON_FINITE)
    return jsonschema.validators.extend(base, type_checker=checker)


def validate(instance, schema) -> None:
    """jsonschema.validate with the gateway's non-finite floats read as numbers (ValidationError otherwise)."""
    validator_class()(schema).validate(instance)
