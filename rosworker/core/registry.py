"""A name -> item registry that families fill in their start: the base of the samplers (``samplers.py``)
and of the observables (``notifier.py``)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ipc.errors import IpcError


class Registry:
    """What families registered, by name; :meth:`get` refuses (``bad-request``) a name nobody registered,
    with ``missing(names)`` as the message."""

    def __init__(self, missing: Callable[[tuple[str, ...]], str]) -> None:
        self._items: dict[str, Any] = {}
        self._missing = missing

    def add(self, name: str, item: Any, taken: str) -> None:
        """Register ``item`` as ``name`` (ValueError ``taken`` when it is registered already)."""
        if name in self._items:
            raise ValueError(taken)
        self._items[name] = item

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._items)

    def get(self, name: str) -> Any:
        item = self._items.get(name)
        if item is None:
            raise IpcError("bad-request", self._missing(self.names))
        return item
