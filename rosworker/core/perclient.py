"""How many records each client holds, for a family's per-client cap (cyclic subscriptions, triggers)."""

from __future__ import annotations


class PerClient(dict[str, int]):
    """client -> records it holds; a client holding none is not kept, and ``""`` (no client) is never counted."""

    def held(self, client: str) -> int:
        return self.get(client, 0) if client else 0

    def take(self, client: str) -> None:
        if client:
            self[client] = self.get(client, 0) + 1

    def give(self, client: str) -> None:
        if client:
            held = self.get(client, 0) - 1
            if held > 0:
                self[client] = held
            else:
                self.pop(client, None)
