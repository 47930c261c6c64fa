"""The demo robot's arm calibration: a service and an action, for the README's operations examples.

    /arm/calibration  ⇄ /arm/calibrate         (std_srvs/srv/Trigger: answers at once)
                      ⇄ /arm/long_calibration  (test_msgs/action/Fibonacci: one step of `order` every
                                                second, feedback after each, cancellable; order < 0 is
                                                rejected, order > 46 (past int32) is aborted after its
                                                first step)

The node runs in the demo robot's single-threaded executor beside the sensors, so the action's
steps wait on timers (an ``async`` execute callback), never on ``sleep``.
"""

from __future__ import annotations

from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.node import Node
from rclpy.task import Future
from std_srvs.srv import Trigger
from test_msgs.action import Fibonacci

from common.harness import fibonacci

STEP_S = 1.0
MAX_ORDER = 46   # fib(47) does not fit the int32 of Fibonacci's sequence


def build() -> Node:
    node = Node("calibration", namespace="/arm")
    count = {"n": 0}

    def calibrate(_request, response):
        count["n"] += 1
        response.success = True
        response.message = f"arm calibrated ({count['n']} times since start)"
        return response

    node.create_service(Trigger, "calibrate", calibrate)

    def pause(seconds: float) -> Future:
        done = Future()

        def fire():
            timer.cancel()
            node.destroy_timer(timer)
            done.set_result(True)

        timer = node.create_timer(seconds, fire)
        return done

    async def execute(goal_handle):
        return await fibonacci.execute(goal_handle, Fibonacci, lambda: pause(STEP_S),
                                       aborts=lambda order: order > MAX_ORDER)

    node._long_calibration = ActionServer(   # kept with the node
        node, Fibonacci, "long_calibration", execute_callback=execute,
        goal_callback=lambda request: GoalResponse.REJECT if request.order < 0 else GoalResponse.ACCEPT,
        cancel_callback=lambda _handle: CancelResponse.ACCEPT)
    return node
