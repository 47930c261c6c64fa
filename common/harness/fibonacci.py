"""The goal loop of a ``Fibonacci`` action server (test_msgs/action/Fibonacci): the demo robot's
``/arm/long_calibration`` (demo/calibration.py) and the tests' action servers (tests/support/rosops.py).
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable


async def execute(goal_handle, cls, pause: Callable[[], Awaitable], aborts: Callable[[int], bool]):
    """Compute ``order`` numbers, one after each ``await pause()``, with feedback after each.

    A cancel request ends the goal ``canceled`` (with the numbers so far) after the pause it came in;
    ``aborts(order)`` ends it ``aborted`` after its first pause.  Returns the result (``cls.Result``).
    """
    order = goal_handle.request.order
    sequence = [0, 1]
    feedback = cls.Feedback()
    for i in range(1, max(1, order)):
        await pause()
        if goal_handle.is_cancel_requested:
            goal_handle.canceled()
            return cls.Result(sequence=sequence)
        if aborts(order):
            goal_handle.abort()
            return cls.Result()
        sequence.append(sequence[i] + sequence[i - 1])
        feedback.sequence = sequence
        goal_handle.publish_feedback(feedback)
    goal_handle.succeed()
    return cls.Result(sequence=sequence)
