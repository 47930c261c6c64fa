"""What a trigger observes: a collection another family provides (``core/notifier.py``), and the one evaluation.

A trigger's ``source`` names a collection of the core's notifier (``data``,
``faults``, ``logs``: whatever the families provide), its ``target`` what of it
(a topic; an entity's scope as JSON), checked and made canonical by that
collection (``check_target``).  Each trigger is attached as a
:class:`TriggerObserver`; the collection calls it for every change of what it
watches, and :func:`evaluate` runs its condition on the change (or on the value
at its ``path`` in it: a change without that path is not evaluated) and fires
it when the condition holds.  The triggers know no family.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ipc import jsonpointer

from .conditions import fires


def evaluate(trigger: Any, doc: Any, stamp: int, payload: Callable[[str], bytes],
             fire: Callable[..., None]) -> None:
    """``trigger``'s condition on ``doc`` (or the value at its path) after its previous value; when it
    holds, ``fire(trigger, stamp, payload=<the change's JSON in the trigger's bytes mode>)``."""
    value = jsonpointer.resolve(doc, trigger.tokens)
    if value is jsonpointer.MISSING:
        return
    previous, trigger.previous = trigger.previous, value
    if fires(trigger.condition, previous, value):
        fire(trigger, stamp, payload=payload(trigger.bytes))


class TriggerObserver:
    """A trigger as an observer of its collection (``core/notifier.py``)."""

    __slots__ = ("trigger", "fire")

    def __init__(self, trigger: Any, fire: Callable[..., None]):
        self.trigger = trigger
        self.fire = fire

    @property
    def target(self) -> str:
        return self.trigger.target

    @property
    def bytes(self) -> str:
        return self.trigger.bytes

    def changed(self, stamp: int, doc: Any, payload: Callable[[str], bytes]) -> None:
        evaluate(self.trigger, doc, stamp, payload, self.fire)

    def failed(self, stamp: int, message: str) -> None:
        self.fire(self.trigger, stamp, error=message)
