"""What can be observed: a family's collections whose changes observers hear (medkit's ``ResourceChangeNotifier``).

A family *provides* a collection it can tell changes of (:meth:`ChangeNotifier.provide`):
``data`` (every message of a topic, ``data/observable.py``), ``faults`` (every fault
event, ``faults/observable.py``), ``logs`` (every line, ``logs/observable.py``).  An
observer (the triggers of one target, ``triggers/sources.py``; any family: bulk data
may observe ``faults`` for ``fault_confirmed``) is attached with
:meth:`ChangeNotifier.observe` and knows no family.

An observable (ROS thread only):

- ``max_target``: the longest target it takes (characters);
- ``check_target(text) -> text``: the target as kept, or :class:`IpcError`
  (a topic name; an entity's scope as JSON: :func:`parse_scope`);
- ``attach(observer)`` / ``detach(observer)``: from now on / no more;
- ``close()``: detach everything (shutdown).

It calls, for every change of what an observer's ``target`` names (``""``: all):

- ``observer.changed(stamp_ns, doc, payload)``: ``doc`` the change as JSON-ready
  values (the message, the fault event, the log entry), ``payload(bytes_mode)``
  its JSON text (made once per change, whoever asks);
- ``observer.failed(stamp_ns, message)``: a change that could not be read.

An observer has a ``target``; it asks for the payload in the bytes modes it
needs (``array`` or ``base64``: how byte arrays are written).  The cost of a
change nobody observes is one attribute test in the family
(``observable.observers``).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any, Protocol

import orjson

from ipc.errors import IpcError

from .registry import Registry

MAX_SCOPE_NODES = 10000
SCOPE_MAX = 256 * 1024  # characters of a scope target (the entity's node names, as JSON)


class Observer(Protocol):
    target: str

    def changed(self, stamp: int, doc: Any, payload: Callable[[str], bytes]) -> None: ...

    def failed(self, stamp: int, message: str) -> None: ...


class ChangeNotifier(Registry):
    def __init__(self) -> None:
        super().__init__(lambda names: "source: expected one of " + ", ".join(names))

    def provide(self, collection: str, observable: Any) -> None:
        """A family's start: changes of ``collection`` can be observed through ``observable``."""
        self.add(collection, observable, f"{collection!r} is provided already")

    @property
    def collections(self) -> tuple[str, ...]:
        return self.names

    def observe(self, collection: str, observer: Observer) -> None:
        self.get(collection).attach(observer)

    def forget(self, collection: str, observer: Observer) -> None:
        observable = self._items.get(collection)
        if observable is not None:
            observable.detach(observer)

    def close(self) -> None:
        for observable in self._items.values():
            observable.close()


# ---- an entity's scope: the targets of event-driven collections (faults, logs) -------------------------
def parse_scope(text: str, with_code: bool = False) -> dict[str, Any]:
    """The scope a target names: ``{"nodes": [FQN, ...]}`` (an entity's nodes; ``""``: everything),
    with ``"code"`` (a fault code or None) when ``with_code``; IpcError("bad-request") otherwise."""
    if text == "":
        return {"nodes": None, "code": None} if with_code else {"nodes": None}
    try:
        doc = json.loads(text)
    except ValueError:
        doc = None
    nodes = doc.get("nodes") if isinstance(doc, dict) else None
    if not isinstance(nodes, list) or len(nodes) > MAX_SCOPE_NODES \
            or not all(isinstance(n, str) and n.startswith("/") for n in nodes):
        raise IpcError("bad-request", "target: expected {\"nodes\": [node names]}")
    out: dict[str, Any] = {"nodes": sorted(set(nodes))}
    if with_code:
        code = doc.get("code")
        if code is not None and (not isinstance(code, str) or not code or len(code) > 256):
            raise IpcError("bad-request", "target: code must be a fault code or null")
        out["code"] = code
    return out


class ScopedObservable:
    """An event-driven observable whose observers name an entity's scope (:func:`parse_scope`).

    A family keeps one, calls :meth:`notify` with the observers a change concerns (``select``),
    and tests ``observers`` first, so a change nobody watches costs nothing more."""

    max_target = SCOPE_MAX
    with_code = False

    def __init__(self, stats: Any):
        self.stats = stats
        self.observers: list[Observer] = []
        self.scopes: dict[int, dict[str, Any]] = {}   # id(observer) -> its parsed target

    def check_target(self, text: str) -> str:
        parse_scope(text, self.with_code)
        return text

    def scope(self, observer: Observer) -> dict[str, Any]:
        return self.scopes[id(observer)]

    def attach(self, observer: Observer) -> None:
        self.scopes[id(observer)] = parse_scope(observer.target, self.with_code)
        self.observers.append(observer)
        self.indexed()

    def detach(self, observer: Observer) -> None:
        if observer in self.observers:
            self.observers.remove(observer)
            self.scopes.pop(id(observer), None)
            self.indexed()

    def close(self) -> None:
        self.observers.clear()
        self.scopes.clear()
        self.indexed()

    def indexed(self) -> None:
        """The observers changed (a subclass indexes them)."""

    def notify(self, observers: list[Observer], doc: dict[str, Any], stamp: int) -> None:
        """``doc`` changed for ``observers``: each is told once, its payload made once for all."""
        if not observers:
            return
        self.stats.trigger_messages += 1
        text: list[bytes] = []

        def payload(_mode: str) -> bytes:
            if not text:
                text.append(orjson.dumps(doc))
            return text[0]

        for observer in list(observers):
            observer.changed(stamp, doc, payload)

