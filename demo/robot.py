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
    /power/battery_monitor            → /power/battery                   (sensor_msgs/msg/BatteryState, 2 Hz)
    /arm/calibration                  ⇄ /arm/calibrate, /arm/long_calibration (a service and an action:
                                        demo/calibration.py)

The battery does not measure its temperature, current or charge: as BatteryState says, those
are NaN (which JSON cannot carry; see the README on non-finite floats).
The camera's picture is a test pattern: red grows with x (4 per column), green with y
(5 per row), and a bright blue bar sweeps across (one column per frame).
"""

from __future__ import annotations

import math
import signal
import threading
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import BatteryState, FluidPressure, Image, Temperature
from std_msgs.msg import Bool, String

CAMERA_WIDTH, CAMERA_HEIGHT = 64, 48
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _periodic(node: Node, topic: str, cls, hz: float, fill) -> None:
    pub = node.create_publisher(cls, topic, 10)

    def tick():
        msg = cls()
        fill(msg, time.monotonic())
        pub.publish(msg)

    node.create_timer(1.0 / hz, tick)


def build() -> list[Node]:
    engine = Node("temp_sensor", namespace="/powertrain/engine")

    def temperature(msg, t):
        msg.header.stamp = engine.get_clock().now().to_msg()
        msg.header.frame_id = "engine"
        msg.temperature = 90.0 + 5.0 * math.sin(t / 10.0)
        msg.variance = 0.5

    _periodic(engine, "temperature", Temperature, 10, temperature)
    # configurations: the engine's parameters; publish_rate changes the rate above (demo/tuning.py)
    from demo.tuning import tune
    tune(engine)

    brakes = Node("pressure_sensor", namespace="/chassis/brakes")

    def pressure(msg, t):
        msg.header.stamp = brakes.get_clock().now().to_msg()
        msg.header.frame_id = "brakes"
        msg.fluid_pressure = 2.0e6 + 1.0e5 * math.sin(t)
        msg.variance = 10.0

    _periodic(brakes, "pressure", FluidPressure, 20, pressure)

    odometry = Node("odometry", namespace="/chassis")

    def odom(msg, t):
        msg.header.stamp = odometry.get_clock().now().to_msg()
        msg.header.frame_id = "odom"
        msg.child_frame_id = "base_link"
        msg.pose.pose.position.x = 10.0 * math.cos(t / 20.0)
        msg.pose.pose.position.y = 10.0 * math.sin(t / 20.0)
        msg.twist.twist.linear.x = 0.5

    _periodic(odometry, "odom", Odometry, 10, odom)

    lights = Node("controller", namespace="/body/lights")
    state_pub = lights.create_publisher(String, "state", LATCHED)
    state_pub.publish(String(data="off"))
    lights.create_subscription(
        Bool, "command", lambda msg: state_pub.publish(String(data="on" if msg.data else "off")), 10)

    diag = Node("diagnostics_agent")

    def diagnostics(msg, t):
        msg.header.stamp = diag.get_clock().now().to_msg()
        msg.status = [DiagnosticStatus(level=DiagnosticStatus.OK, name="engine", message="running",
                                       hardware_id="ecu-1",
                                       values=[KeyValue(key="rpm", value=str(int(800 + 50 * math.sin(t))))])]

    _periodic(diag, "/diagnostics", DiagnosticArray, 1, diagnostics)

    camera = Node("camera", namespace="/perception")
    frames = [0]

    def image(msg, t):
        msg.header.stamp = camera.get_clock().now().to_msg()
        msg.header.frame_id = "camera"
        msg.height, msg.width, msg.encoding, msg.step = CAMERA_HEIGHT, CAMERA_WIDTH, "rgb8", CAMERA_WIDTH * 3
        msg.data = test_pattern(frames[0])
        frames[0] += 1

    _periodic(camera, "camera/image_raw", Image, 5, image)

    battery = Node("battery_monitor", namespace="/power")

    def battery_state(msg, t):
        msg.header.stamp = battery.get_clock().now().to_msg()
        msg.voltage = 25.2 - 0.5 * (1.0 + math.sin(t / 30.0))
        msg.percentage = 0.8 + 0.1 * math.sin(t / 30.0)
        msg.temperature = msg.current = msg.charge = msg.capacity = math.nan   # not measured
        msg.design_capacity = 20.0
        msg.power_supply_status = BatteryState.POWER_SUPPLY_STATUS_DISCHARGING
        msg.present = True

    _periodic(battery, "battery", BatteryState, 2, battery_state)
    # faults: the battery warns on /diagnostics while its charge is low (demo/battery.py)
    from demo.battery import add_diagnostics

    add_diagnostics(battery)
    _log_lines(engine, brakes, odometry, battery)  # logs (issue 22): /rosout at several levels
    return [engine, brakes, odometry, lights, diag, camera, battery]


# logs (issue 22): what the demo's nodes write to /rosout (GET /apps/{id}/logs, the Logs panel).
def _log_lines(engine: Node, brakes: Node, odometry: Node, battery: Node) -> None:
    """Lines at every level but fatal: debug, info, warning when a value leaves its band, an error now and then."""
    from rclpy.logging import LoggingSeverity

    brakes.get_logger().set_level(LoggingSeverity.DEBUG)
    start = time.monotonic()

    def engine_line():
        temperature = 90.0 + 5.0 * math.sin(time.monotonic() / 10.0)
        if temperature > 94.0:
            engine.get_logger().warning(f"engine temperature high: {temperature:.1f} °C")
        else:
            engine.get_logger().info(f"engine temperature {temperature:.1f} °C")

    def brakes_line():
        brakes.get_logger().debug("brake pressure sampled")

    def odometry_line():
        if int(time.monotonic() - start) % 30 < 10:  # the first line (at 5 s) is one
            odometry.get_logger().error("wheel slip detected on the rear left wheel")
        else:
            odometry.get_logger().info("odometry ok")

    def battery_line():
        percentage = 0.8 + 0.1 * math.sin(time.monotonic() / 30.0)
        if percentage < 0.72:
            battery.get_logger().warning(f"battery low: {percentage:.0%}")
        else:
            battery.get_logger().info(f"battery at {percentage:.0%}")

    engine.create_timer(2.0, engine_line)
    brakes.create_timer(1.0, brakes_line)
    odometry.create_timer(5.0, odometry_line)
    battery.create_timer(3.0, battery_line)


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
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    rclpy.init(signal_handler_options=rclpy.SignalHandlerOptions.NO)
    nodes = build()
    # operations: the arm's calibrate service and long_calibration action
    from demo import calibration

    nodes.append(calibration.build())
    executor = SingleThreadedExecutor()
    for node in nodes:
        executor.add_node(node)
    print("demo robot running: " + ", ".join(n.get_fully_qualified_name() for n in nodes), flush=True)
    try:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.1)
    finally:
        for node in nodes:
            executor.remove_node(node)
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
