"""What triggers observe: a collection another family provides (``core/notifier.py``), and the one evaluation.

A trigger's ``source`` names a collection of the core's notifier (``data``,
``faults``, ``logs``: whatever the families provide), its ``target`` what of it
(a topic; an entity's scope as JSON), checked and made canonical by that
collection (``check_target``).  The triggers of one ``(source, target)`` are
attached together, as one :class:`TriggerGroup`: the collection calls it once
for every change of what they watch, :func:`evaluate` runs each one's
condition on the change (or on the value at its ``path`` in it: a change
without that path is not evaluated), and those that fired are handed on
together (``fire``), so the change crosses to the HTTP workers once however
many of them fired on it.  The triggers know no family.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ipc import jsonpointer

from .conditions import fires


def evaluate(trigger: Any, doc: Any) -> bool:
    """Whether ``trigger``'s condition holds on ``doc`` (or the value at its path) after its previous value
    (the value is kept as the next one's previous)."""
    value = jsonpointer.resolve(doc, trigger.tokens)
    if value is jsonpointer.MISSING:
        return False
    previous, trigger.previous = trigger.previous, value
    return fires(trigger.condition, previous, value)


class TriggerGroup:
    """The triggers of one ``(source, target)``, as one observer of their collection (``core/notifier.py``).

    ``fire(stamp, fired, payload=...)`` gets the triggers a change fired (in the order they were
    attached) and the change's ``payload(bytes_mode)``; ``fire(stamp, triggers, error=...)`` a change
    that could not be read (every trigger of the group)."""

    __slots__ = ("source", "target", "triggers", "fire")

    def __init__(self, source: str, target: str, fire: Callable[..., None]):
        self.source = source
        self.target = target
        self.triggers: list[Any] = []
        self.fire = fire

    def changed(self, stamp: int, doc: Any, payload: Callable[[str], bytes]) -> None:
        fired = [trigger for trigger in list(self.triggers) if evaluate(trigger, doc)]
        if fired:
            self.fire(stamp, fired, payload=payload)

    def failed(self, stamp: int, message: str) -> None:
        self.fire(stamp, list(self.triggers), error=message)
