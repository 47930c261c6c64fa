"""rosworker/configurations/values.py: ParameterValue <-> JSON, exactly, and the classification of a refusal."""

from __future__ import annotations

import math

import pytest
from rcl_interfaces.msg import ParameterType as T

from ipc.errors import IpcError
from rosworker.configurations.values import refused, to_value, type_name, value_json

CASES = [
    (T.PARAMETER_BOOL, True, "bool"),
    (T.PARAMETER_INTEGER, -(2**63), "int"),
    (T.PARAMETER_INTEGER, 2**63 - 1, "int"),
    (T.PARAMETER_DOUBLE, 0.1, "double"),
    (T.PARAMETER_DOUBLE, "NaN", "double"),
    (T.PARAMETER_DOUBLE, "-Infinity", "double"),
    (T.PARAMETER_STRING, "ünï ✓", "string"),
    (T.PARAMETER_BYTE_ARRAY, [0, 128, 255], "byte_array"),
    (T.PARAMETER_BOOL_ARRAY, [True, False], "bool_array"),
    (T.PARAMETER_INTEGER_ARRAY, [1, -(2**63)], "int_array"),
    (T.PARAMETER_DOUBLE_ARRAY, [1.5, "Infinity", "NaN"], "double_array"),
    (T.PARAMETER_STRING_ARRAY, ["a", ""], "string_array"),
    (T.PARAMETER_STRING_ARRAY, [], "string_array"),
]


@pytest.mark.parametrize(("current", "data", "name"), CASES)
def test_round_trip(current, data, name):
    value = to_value(data, current)
    assert value.type == current and type_name(value) == name
    assert value_json(value) == data


def test_an_integer_for_a_double_is_a_double():
    value = to_value(3, T.PARAMETER_DOUBLE)
    assert value.type == T.PARAMETER_DOUBLE and value_json(value) == 3.0
    assert math.isinf(to_value("Infinity", T.PARAMETER_DOUBLE).double_value)


@pytest.mark.parametrize(("data", "current", "sent"), [
    ("seven", T.PARAMETER_INTEGER, T.PARAMETER_STRING),   # the node says what it thinks of a type change
    (2.5, T.PARAMETER_INTEGER, T.PARAMETER_DOUBLE),
    ([1, 2], T.PARAMETER_BYTE_ARRAY, T.PARAMETER_BYTE_ARRAY),
    ([1, 300], T.PARAMETER_BYTE_ARRAY, T.PARAMETER_INTEGER_ARRAY),
    ("NaN", T.PARAMETER_STRING, T.PARAMETER_STRING),
])
def test_a_value_of_another_type_goes_as_its_own_type(data, current, sent):
    assert to_value(data, current).type == sent


@pytest.mark.parametrize("data", [None, {"a": 1}, [], [1, "a"], 2**63, [1.5, True], [[1]]])
def test_no_parameter_value(data):
    with pytest.raises(IpcError) as err:
        to_value(data, T.PARAMETER_INTEGER)
    assert err.value.code == "invalid-parameter-value" and err.value.params == {"expected_type": "int"}


@pytest.mark.parametrize(("reason", "code"), [
    ("Trying to set a read-only parameter: robot_id.", "parameter-read-only"),
    ("parameter 'x' cannot be set because it is read-only", "parameter-read-only"),
    ("Wrong parameter type, expected 'Type.INTEGER' got 'Type.STRING'", "invalid-parameter-value"),
    ("", "invalid-parameter-value"),
])
def test_refusals(reason, code):
    err = refused(reason, "x")
    assert err.code == code and err.message


def test_empty_array_with_a_scalar_type_has_no_type():
    with pytest.raises(IpcError):
        to_value([], T.PARAMETER_DOUBLE)
