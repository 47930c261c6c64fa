"""rosworker/operations: its pure parts (which services are operations, interface types, the restart
record.  The clients themselves are tested through the real gateway (tests/system/operations/test_operations*.py)."""

from __future__ import annotations

import json

import pytest

from ipc.errors import IpcError
from rosworker.operations import goals, interfaces
from rosworker.operations.actions import Goal


def test_node_operations_leave_out_parameter_type_description_and_hidden_action_services():
    services = [
        ("/arm/calib/describe_parameters", ["rcl_interfaces/srv/DescribeParameters"]),
        ("/arm/calib/get_parameters", ["rcl_interfaces/srv/GetParameters"]),
        ("/arm/calib/set_parameters_atomically", ["rcl_interfaces/srv/SetParametersAtomically"]),
        ("/arm/calib/get_type_description", ["type_description_interfaces/srv/GetTypeDescription"]),
        ("/arm/fib/_action/send_goal", ["test_msgs/action/Fibonacci_SendGoal"]),
        ("/arm/fib/_action/get_result", ["test_msgs/action/Fibonacci_GetResult"]),
        ("/arm/fib/_action/cancel_goal", ["action_msgs/srv/CancelGoal"]),
        ("/arm/calibrate", ["std_srvs/srv/Trigger"]),
        ("/arm/get_parameters", ["std_srvs/srv/Trigger"]),   # a user's service of that name is one
        ("/arm/untyped", []),
    ]
    assert interfaces.node_operations(services) == [
        {"kind": "service", "path": "/arm/calibrate", "name": "calibrate", "type": "std_srvs/srv/Trigger"},
        {"kind": "service", "path": "/arm/get_parameters", "name": "get_parameters",
         "type": "std_srvs/srv/Trigger"},
        {"kind": "action", "path": "/arm/fib", "name": "fib", "type": "test_msgs/action/Fibonacci"},
    ]


def test_interfaces_load_only_from_their_kind_and_from_ros_packages():
    assert interfaces.load_interface("std_srvs/srv/Trigger", "srv").__name__ == "Trigger"
    assert interfaces.load_interface("test_msgs/action/Fibonacci", "action").__name__ == "Fibonacci"
    for name, kind, code_text in (("std_srvs/srv/Trigger", "action", "Invalid action type"),
                                  ("std_msgs/msg/String", "srv", "Invalid service type"),
                                  ("antigravity/srv/Fly", "srv", "not installed"),
                                  ("std_srvs/srv/Nope", "srv", "not installed"),
                                  ("../srv/X", "srv", "Invalid service type")):
        with pytest.raises(IpcError) as err:
            interfaces.load_interface(name, kind)
        assert err.value.code == "type-introspection-failed" and code_text in err.value.message


def test_type_info_has_schemas_and_defaults_including_non_finite_floats():
    info = interfaces.type_info("test_msgs/srv/BasicTypes", "srv")
    assert set(info) == {"request", "response", "default_value"}
    assert {"type": "string", "enum": ["NaN", "Infinity", "-Infinity"]} in \
        info["request"]["properties"]["float32_value"]["anyOf"]
    assert info["default_value"]["response"]["int64_value"] == 0
    assert interfaces.type_info("nope_pkg/srv/X", "srv") is None


def test_the_restart_record_reads_every_running_goal_as_lost(tmp_path):
    goal = Goal(bytes(range(16)), "/arm/fib", "test_msgs/action/Fibonacci", "calib")
    records = [{"id": goal.id, "action": goal.path, "type": goal.type_name, "entity_id": "calib",
                "created": 5.0, "message": None},
               {"id": "zz", "action": "/x", "type": "t"},     # not hex: skipped
               {"action": "/x"}]                               # incomplete: skipped
    (tmp_path / goals.STATE_FILE).write_text(json.dumps(records))
    [lost] = goals.load_restart(str(tmp_path))
    wire = lost.wire()
    assert wire["id"] == goal.id and wire["status"] == "failed" and wire["ros2_status"] == "unknown"
    assert "restarted" in wire["message"] and wire["created"] == 5.0
    (tmp_path / goals.STATE_FILE).write_text("{not json")
    assert goals.load_restart(str(tmp_path)) == []
    assert goals.load_restart(str(tmp_path / "none")) == []
