"""The waiter: a thread that sleeps in rcl's wait set on the ROS thread's behalf, and wakes it.

Who waits on what, on which thread:

- The ROS thread (``executor.py``) sleeps in one ``zmq.Poller.poll`` over the work socket, the
  events socket and the wake-up pipe, until the next timer or the next time a poller asked to be
  run (a deadline).  It never polls ROS entities on a clock.
- This thread sleeps in an rcl wait set (rclpy's ``_rclpy.WaitSet``, as rclpy's own executors
  use it) over the entities that have work open, which the ROS thread names before it sleeps
  (:meth:`Waiter.arm`: subscriptions with a reader, service, parameter and action clients with
  calls or goals open), plus one guard condition.  When one of them is ready it notes so,
  disarms itself and writes one byte to the ROS thread's wake-up pipe; the ROS thread takes what
  came and, at the end of its round, arms it again.

Why it is race-free:

- Only the ROS thread creates, destroys and takes.  This thread only waits, and rcl allows a
  ``take`` on an entity while another thread waits on it (rclpy's multi-threaded executor does
  the same).
- No entity is destroyed while it is in the wait set being waited on: before destroying one the
  ROS thread calls :meth:`Waiter.release` (``node.py`` does, for every destroy); if the entity is
  armed, the guard condition is triggered and the ROS thread waits until this thread has left
  ``rcl_wait`` and dropped its wait set.  This thread also holds each handle's use count while it
  waits (``with handle``, as rclpy's executors do), so a destroy that came anyway would be put
  off, never a use after free.
- Readiness is level-triggered and this thread is one-shot: after it reported, it waits for the
  next :meth:`arm`.  What the ROS thread leaves for a later round (a trigger's round budget) makes
  one wake-up per round, never a spin.
- :meth:`arm` with the set already armed does nothing: a round that changed nothing (a warm
  sample) costs no hand-off.  A triggered guard condition stays triggered until a wait sees it,
  so one that comes after this thread was asked to stop waiting is not lost; one that finds it
  not asked (late from a finished hand-off) only makes it wait again.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Sequence

log = logging.getLogger("sovd.rosworker.waiter")

RELEASE_TIMEOUT = 5.0   # seconds the ROS thread waits for this thread to leave rcl_wait (it takes µs)
FAILURE_PAUSE = 0.05    # seconds this thread pauses after a wait that failed, before it wakes the ROS thread


class Waiter:
    """The thread that waits in rcl for the ROS thread (see the module's docstring)."""

    def __init__(self, context, wake: Callable[[], None]):
        from rclpy.action import ActionClient
        from rclpy.client import Client
        from rclpy.impl.implementation_singleton import rclpy_implementation
        from rclpy.subscription import Subscription

        self._rclpy = rclpy_implementation
        self._kinds = (Subscription, Client, ActionClient)
        self._context = context
        self._wake = wake
        self._guard = rclpy_implementation.GuardCondition(context.handle)
        self._cond = threading.Condition()
        self._armed: tuple = ()          # what this thread is to wait on
        self._keys: frozenset[int] = frozenset()
        self._offered = False            # a set is armed that this thread has not picked up yet
        self._in_wait = False            # this thread holds the armed set (in rcl_wait, or about to be)
        self._hold = False               # the ROS thread asked it to give the set back
        self._fired = False              # something was ready: the ROS thread has not looked yet
        self._stopping = False
        self.reports = 0                 # times it woke the ROS thread
        self.failures = 0                # waits that failed (logged the first time and every 1000th)
        self._thread = threading.Thread(target=self._run, name="ros-waiter", daemon=True)

    def start(self) -> None:
        self._thread.start()

    # ---- ROS thread ---------------------------------------------------------------------------
    def arm(self, entities: Sequence) -> None:
        """Wait on ``entities`` (rclpy subscriptions, clients, action clients) until one is ready."""
        keys = frozenset(map(id, entities))
        with self._cond:
            if keys == self._keys and (self._offered or self._in_wait):
                return
            if self._in_wait:
                self._quiesce()
            self._armed, self._keys = tuple(entities), keys
            self._offered, self._hold = bool(entities), False
            self._cond.notify_all()

    def release(self, entity) -> None:
        """Before ``entity`` is destroyed: out of the wait set if it is in it."""
        with self._cond:
            if id(entity) in self._keys:
                if self._in_wait:
                    self._quiesce()
                self._armed, self._keys, self._offered = (), frozenset(), False

    def fired(self) -> bool:
        """Whether something became ready since the last call (and so the ROS thread was woken)."""
        with self._cond:
            fired, self._fired = self._fired, False
            return fired

    def stop(self) -> None:
        with self._cond:
            self._stopping = self._hold = True
            self._cond.notify_all()
        self._guard.trigger_guard_condition()
        self._thread.join(RELEASE_TIMEOUT)
        if self._thread.is_alive():
            log.error("the waiter thread did not stop within %g s", RELEASE_TIMEOUT)
            return
        self._guard.destroy_when_not_in_use()

    def _quiesce(self) -> None:
        """Make this thread leave rcl_wait and give its set back (condition held)."""
        self._hold = True
        self._guard.trigger_guard_condition()
        if not self._cond.wait_for(lambda: not self._in_wait, RELEASE_TIMEOUT):
            # Never seen: rcl_wait returns on a guard condition at once.  Nothing is destroyed
            # under it anyway (the handles' use counts put a destroy off).
            log.error("the waiter thread did not leave rcl_wait within %g s", RELEASE_TIMEOUT)

    # ---- this thread ----------------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._stopping or self._offered)
                if self._stopping:
                    return
                armed = self._armed
                self._offered, self._in_wait = False, True
            while True:
                try:
                    ready = self._wait(armed)
                except Exception:  # noqa: BLE001 - a wait set that could not be made: wake the ROS thread
                    self.failures += 1
                    if self.failures == 1 or self.failures % 1000 == 0:
                        log.exception("waiting on %d ROS entities failed (%d times)", len(armed), self.failures)
                    time.sleep(FAILURE_PAUSE)  # its pollers look at their entities: no spin if it persists
                    ready = True
                with self._cond:
                    # Only the guard, and nobody asked: left triggered by an earlier hand-off; wait again.
                    if ready or self._hold or self._stopping:
                        self._in_wait = False
                        if ready:
                            self._fired = True
                            self.reports += 1
                        self._cond.notify_all()
                        break
            if ready:
                self._wake()

    def _wait(self, armed: tuple) -> bool:
        """One wait over ``armed`` and the guard condition: whether anything but the guard is ready."""
        subs, clients, actions = [], [], []
        counts = [0, 1, 0, 0, 0, 0]   # subscriptions, guard conditions, timers, clients, services, events
        with contextlib.ExitStack() as held:
            for entity in armed:
                try:
                    if isinstance(entity, self._kinds[0]):
                        held.enter_context(entity.handle)
                        subs.append(entity.handle)
                        counts[0] += 1
                    elif isinstance(entity, self._kinds[1]):
                        held.enter_context(entity.handle)
                        clients.append(entity.handle)
                        counts[3] += 1
                    elif isinstance(entity, self._kinds[2]):
                        held.enter_context(entity)
                        actions.append(entity)
                        n = entity.get_num_entities()
                        counts[0] += n.num_subscriptions
                        counts[1] += n.num_guard_conditions
                        counts[2] += n.num_timers
                        counts[3] += n.num_clients
                        counts[4] += n.num_services
                        counts[5] += n.num_events
                except Exception:  # noqa: BLE001 - InvalidHandle: destroyed meanwhile, nothing to wait on
                    continue
            held.enter_context(self._context.handle)
            wait_set = self._rclpy.WaitSet(*counts, self._context.handle)
            wait_set.clear_entities()
            for handle in subs:
                wait_set.add_subscription(handle)
            for handle in clients:
                wait_set.add_client(handle)
            for action in actions:
                action.add_to_wait_set(wait_set)
            wait_set.add_guard_condition(self._guard)
            wait_set.wait(-1)
            if wait_set.get_ready_entities("subscription") or wait_set.get_ready_entities("client"):
                return True
            return any(any(action._client_handle.is_ready(wait_set)) for action in actions)
