"""The waiter thread (rosworker/core/waiter.py) over real rclpy entities in this process.

It wakes its owner when an armed subscription gets a message (and only once per arm), gives its
wait set back at once when an armed entity is to be destroyed, and a set armed again and again
before it was even picked up never stalls the arming thread.
"""

from __future__ import annotations

import threading
import time

import pytest

from common.harness.procs import poll_until


@pytest.fixture
def ros():
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64

    from rosworker.core.waiter import Waiter

    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=rclpy.SignalHandlerOptions.NO)
    node = Node("waiter_test", context=context, start_parameter_services=False, enable_rosout=False)
    profile = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    topic = f"/waiter_test_{time.monotonic_ns()}"
    pub = node.create_publisher(Float64, topic, profile)
    sub = node.create_subscription(Float64, topic, lambda _msg: None, profile)
    woken = threading.Event()
    waiter = Waiter(context, woken.set)
    waiter.start()
    poll_until(lambda: pub.get_subscription_count() == 1, 10, message="the subscription matched")
    yield waiter, woken, node, pub, sub, Float64
    waiter.stop()
    node.destroy_node()
    context.try_shutdown()


def test_a_message_wakes_the_owner_once_per_arm(ros):
    waiter, woken, _node, pub, sub, cls = ros
    waiter.arm([sub])
    assert not woken.wait(0.3) and not waiter.fired()  # nothing came: no wake-up
    pub.publish(cls(data=1.0))
    assert woken.wait(5), "the message did not wake the owner"
    assert waiter.fired() and not waiter.fired()       # told once
    woken.clear()
    assert not woken.wait(0.3)                         # not armed again: the untaken message wakes nobody
    waiter.arm([sub])
    assert woken.wait(5)                               # armed again: it is still there (level-triggered)
    assert sub.handle.take_message(cls, False) is not None
    woken.clear()
    waiter.arm([sub])
    assert not woken.wait(0.3)                         # taken: quiet again
    assert waiter.reports == 2


def test_an_armed_subscription_is_released_before_it_is_destroyed(ros):
    waiter, woken, node, pub, sub, cls = ros
    waiter.arm([sub])
    time.sleep(0.1)                                    # the waiter is in rcl_wait with it
    started = time.monotonic()
    waiter.release(sub)
    assert time.monotonic() - started < 1.0            # the guard condition gets it out at once
    node.destroy_subscription(sub)
    pub.publish(cls(data=2.0))
    assert not woken.wait(0.3) and waiter.failures == 0


def test_arming_again_before_the_set_was_picked_up_never_stalls(ros):
    waiter, _woken, node, _pub, sub, cls = ros
    other = node.create_subscription(cls, "/waiter_test_other", lambda _msg: None, 10)
    started = time.monotonic()
    for i in range(2000):                              # the waiter thread may not even have run meanwhile
        waiter.arm([sub] if i % 2 else [other])
    assert time.monotonic() - started < 5.0
    waiter.release(other)
    node.destroy_subscription(other)
    assert waiter.failures == 0
