"""The demo engine's ROS 2 parameters, for the README's configurations examples (not part of the gateway).

``/powertrain/engine/temp_sensor`` declares:

    publish_rate   double, 0.5–50 Hz   the temperature's rate: a change takes effect at once
    sensor_id      string, read-only   set at start; a PUT is refused (403)
    filter_window  int, 1–20           samples averaged; 50 is refused with the node's own reason (400)
"""

from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter


def tune(node: Node) -> None:
    """Declare the parameters on ``node``, whose one timer (the temperature's) follows publish_rate."""
    timer = next(iter(node.timers))
    node.declare_parameter("publish_rate", 1e9 / timer.timer_period_ns, ParameterDescriptor(
        description="temperature messages per second",
        floating_point_range=[FloatingPointRange(from_value=0.5, to_value=50.0, step=0.0)]))
    node.declare_parameter("sensor_id", "ecu-1-temp", ParameterDescriptor(
        description="the sensor's serial number", read_only=True))
    node.declare_parameter("filter_window", 5, ParameterDescriptor(
        description="samples averaged", integer_range=[IntegerRange(from_value=1, to_value=20, step=1)]))

    def changed(params: list[Parameter]) -> None:
        for p in params:
            if p.name == "publish_rate" and p.type_ == Parameter.Type.DOUBLE:
                timer.timer_period_ns = int(1e9 / p.value)

    node.add_post_set_parameters_callback(changed)
