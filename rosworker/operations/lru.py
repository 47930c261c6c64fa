"""The LRU order that the service and the action clients share (the ``max_operation_clients`` cap).

Each kind keeps its clients in an ``OrderedDict`` by path, least recently used first; what counts
as busy (calls or goals open) and how one is destroyed is the kind's own.
"""

from __future__ import annotations

import collections
from collections.abc import Callable
from typing import Any


def reuse(entries: collections.OrderedDict[str, Any], path: str, type_name: str) -> Any:
    """The pooled client of ``path`` if it is of ``type_name`` (made the most recently used), else None."""
    pooled = entries.get(path)
    if pooled is not None and pooled.type_name == type_name:
        entries.move_to_end(path)
        return pooled
    return None


def make_room(entries: collections.OrderedDict[str, Any], cap: int, busy: Callable[[Any], bool],
              destroy: Callable[[str], None]) -> None:
    """Destroy the least recently used clients that are not ``busy`` until one more fits under ``cap``;
    when every one is busy the cap is exceeded until they finish."""
    while len(entries) >= cap:
        oldest = next((path for path, pooled in entries.items() if not busy(pooled)), None)
        if oldest is None:
            return
        destroy(oldest)
