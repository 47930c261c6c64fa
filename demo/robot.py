"""A small demo vehicle: a few ROS 2 nodes publishing sensor-like topics.

Not part of the gateway.  ``make run`` starts it beside the gateway so that a
newcomer can read live data at once::

    /powertrain/engine/temp_sensor    → /powertrain/engine/temperature   (sensor_msgs/msg/Temperature, 10 Hz)
    /chassis/brakes/pressure_sensor   → /chassis/brakes/pressure         (sensor_msgs/msg/FluidPressure, 20 Hz)
    /chassis/odometry                 → /chassis/odom                    (nav_msgs/msg/Odometry, 10 Hz)
    /body/lights/controller           ← /body/lights/command (std_msgs/msg/Bool)
                                      → /body/lights/state   (std_msgs/msg/String, latched)
    /diagnostics_agent                → /diagnostics                     (diagnostic_msgs/msg/DiagnosticArray, 1 Hz)
    /perception/camera                → /perception/camera/image_raw     (sensor_msgs/msg/Image, 64x48 rgb8, 5 Hz)
    /power/battery_monitor            → /power/battery                   (sensor_msgs/msg/BatteryState, 2 Hz:
                                                                          demo/battery.py)
    /arm/calibration                  ⇄ /arm/calibrate, /arm/long_calibration (a service and an action:
                                        demo/calibration.py)

What happens over time, counted from the start (the README's examples wait for these):

- the engine warms and cools between 72 and 88 °C every ``ENGINE_PERIOD`` s: it passes 80 °C on
  the way up once a cycle (the README's LeaveRange trigger), and logs a warning above 86 °C;
- the rear left wheel slips for ``SLIP_FOR`` s every ``SLIP_PERIOD`` s, first ``SLIP_AFTER`` s after
  the start: the odometry logs an error every second and reports ``odometry: Wheel slip`` at
  ERROR on /diagnostics (the fault ``ODOMETRY_WHEEL_SLIP`` of the app ``odometry``), OK otherwise;
- the battery is low soon after the start, and again every few minutes (demo/battery.py).

The battery does not measure its temperature, current or charge: as BatteryState says, those
are NaN (which JSON cannot carry; see the README on non-finite floats).
The camera's picture is a test pattern: red grows with x (4 per column), green with y
(5 per row), and a bright blue bar sweeps across (one column per frame).
"""

from __future__ import annotations

import math
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import BatteryState, FluidPressure, Image, Temperature
from std_msgs.msg import Bool, String

from common.harness import rosmain

CAMERA_WIDTH, CAMERA_HEIGHT = 64, 48
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
ENGINE_PERIOD = 30.0   # seconds of one warm-up and cool-down of the engine
ENGINE_HOT = 86.0      # °C above which the engine logs a warning
SLIP_PERIOD, SLIP_FOR, SLIP_AFTER = 30.0, 6.0, 5.0   # seconds: the wheel slips for 6 s of every 30 s


def engine_temperature(t: float) -> float:
    """°C, ``t`` seconds after the start: 82 and rising at first, 72 … 88 (warnings within seconds)."""
    return 80.0 + 8.0 * math.sin(2 * math.pi * t / ENGINE_PERIOD + math.asin(0.25))


def slipping(t: float) -> bool:
    return t >= SLIP_AFTER and (t - SLIP_AFTER) % SLIP_PERIOD < SLIP_FOR


def _periodic(node: Node, topic: str, cls, hz: float, fill, start: float) -> None:
    pub = node.create_publisher(cls, topic, 10)

    def tick():
        msg = cls()
        fill(msg, time.monotonic() - start)
        pub.publish(msg)

    node.create_timer(1.0 / hz, tick)


def _every(node: Node, seconds: float, fn, start: float) -> None:
    """``fn(t)`` every ``seconds``, ``t`` counted from the start."""
    node.create_timer(seconds, lambda: fn(time.monotonic() - start))


def _diagnostics(node: Node, status_at, start: float) -> None:
    """Publish ``status_at(t)`` on /diagnostics from ``node`` once a second."""
    def fill(msg, t):
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.status = [status_at(t)]

    _periodic(node, "/diagnostics", DiagnosticArray, 1, fill, start)


def build(start: float | None = None) -> list[Node]:
    start = time.monotonic() if start is None else start
    engine = Node("temp_sensor", namespace="/powertrain/engine")

    def temperature(msg, t):
        msg.header.stamp = engine.get_clock().now().to_msg()
        msg.header.frame_id = "engine"
        msg.temperature = engine_temperature(t)
        msg.variance = 0.5

    _periodic(engine, "temperature", Temperature, 10, temperature, start)
    # configurations: the engine's parameters; publish_rate changes the rate above (demo/tuning.py)
    from demo.tuning import tune
    tune(engine)

    brakes = Node("pressure_sensor", namespace="/chassis/brakes")

    def pressure(msg, t):
        msg.header.stamp = brakes.get_clock().now().to_msg()
        msg.header.frame_id = "brakes"
        msg.fluid_pressure = 2.0e6 + 1.0e5 * math.sin(t)
        msg.variance = 10.0

    _periodic(brakes, "pressure", FluidPressure, 20, pressure, start)

    odometry = Node("odometry", namespace="/chassis")

    def odom(msg, t):
        msg.header.stamp = odometry.get_clock().now().to_msg()
        msg.header.frame_id = "odom"
        msg.child_frame_id = "base_link"
        msg.pose.pose.position.x = 10.0 * math.cos(t / 20.0)
        msg.pose.pose.position.y = 10.0 * math.sin(t / 20.0)
        msg.twist.twist.linear.x = 0.5

    _periodic(odometry, "odom", Odometry, 10, odom, start)
    # faults: the wheel slip on /diagnostics, named for the node as diagnostic_updater names statuses
    _diagnostics(odometry, lambda t: DiagnosticStatus(
        level=DiagnosticStatus.ERROR if slipping(t) else DiagnosticStatus.OK, name="odometry: Wheel slip",
        message="rear left wheel slipping" if slipping(t) else "ok", hardware_id="wheel-rl",
        values=[KeyValue(key="wheel", value="rear left"),
                KeyValue(key="slip_ratio", value=f"{0.35 if slipping(t) else 0.02:.2f}")]), start)

    lights = Node("controller", namespace="/body/lights")
    state_pub = lights.create_publisher(String, "state", LATCHED)
    state_pub.publish(String(data="off"))
    lights.create_subscription(
        Bool, "command", lambda msg: state_pub.publish(String(data="on" if msg.data else "off")), 10)

    diag = Node("diagnostics_agent")
    _diagnostics(diag, lambda t: DiagnosticStatus(
        level=DiagnosticStatus.OK, name="engine", message="running", hardware_id="ecu-1",
        values=[KeyValue(key="rpm", value=str(int(800 + 50 * math.sin(t))))]), start)

    camera = Node("camera", namespace="/perception")
    frames = [0]

    def image(msg, t):
        msg.header.stamp = camera.get_clock().now().to_msg()
        msg.header.frame_id = "camera"
        msg.height, msg.width, msg.encoding, msg.step = CAMERA_HEIGHT, CAMERA_WIDTH, "rgb8", CAMERA_WIDTH * 3
        msg.data = test_pattern(frames[0])
        frames[0] += 1

    _periodic(camera, "camera/image_raw", Image, 5, image, start)

    # The battery: one charge for its BatteryState, its log lines and its /diagnostics (demo/battery.py)
    from demo import battery as pack

    battery = Node("battery_monitor", namespace="/power")

    def battery_state(msg, t):
        msg.header.stamp = battery.get_clock().now().to_msg()
        pack.fill(msg, t)

    _periodic(battery, "battery", BatteryState, 2, battery_state, start)
    _diagnostics(battery, pack.status, start)
    _every(battery, 3.0, lambda t: pack.log_line(battery.get_logger(), t), start)
    _log_lines(engine, brakes, odometry, start)  # logs (issue 22): /rosout at several levels
    return [engine, brakes, odometry, lights, diag, camera, battery]


# logs (issue 22): what the demo's nodes write to /rosout (GET /apps/{id}/logs, the Logs panel).
def _log_lines(engine: Node, brakes: Node, odometry: Node, start: float) -> None:
    """Lines at every level but fatal: debug, info, a warning when the engine runs hot, an error while
    the wheel slips."""
    from rclpy.logging import LoggingSeverity

    brakes.get_logger().set_level(LoggingSeverity.DEBUG)

    def engine_line(t):
        temperature = engine_temperature(t)
        if temperature > ENGINE_HOT:
            engine.get_logger().warning(f"engine temperature high: {temperature:.1f} °C")
        else:
            engine.get_logger().info(f"engine temperature {temperature:.1f} °C")

    def odometry_line(t):
        if slipping(t):
            odometry.get_logger().error("wheel slip detected on the rear left wheel")
        elif int(t) % 5 == 0:
            odometry.get_logger().info("odometry ok")

    _every(engine, 2.0, engine_line, start)
    _every(brakes, 1.0, lambda t: brakes.get_logger().debug("brake pressure sampled"), start)
    _every(odometry, 1.0, odometry_line, start)


def test_pattern(frame: int) -> bytes:
    """One rgb8 picture of the camera (see the module docstring)."""
    bar = frame % CAMERA_WIDTH
    pixels = bytearray(CAMERA_WIDTH * CAMERA_HEIGHT * 3)
    for y in range(CAMERA_HEIGHT):
        for x in range(CAMERA_WIDTH):
            i = (y * CAMERA_WIDTH + x) * 3
            pixels[i], pixels[i + 1], pixels[i + 2] = 4 * x, 5 * y, 255 if x == bar else 40
    return bytes(pixels)


def main() -> None:
    stop = rosmain.init()
    nodes = build()
    # operations: the arm's calibrate service and long_calibration action
    from demo import calibration

    nodes.append(calibration.build())
    print("demo robot running: " + ", ".join(n.get_fully_qualified_name() for n in nodes), flush=True)
    rosmain.spin(nodes[0], stop, nodes[1:], timeout=0.1)


if __name__ == "__main__":
    main()
