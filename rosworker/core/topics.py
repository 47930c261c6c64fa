"""Subscriptions that one family owns and the data family's pool reads through: one subscription per topic.

The bulk-data family records some topics (``rosworker/bulk_data/recorder.py``); a sample of
such a topic must not subscribe it a second time.  The owner :meth:`SharedTopics.provide`\\ s
a function ``(topic, type_name | None) -> subscription | None``; the data family
:meth:`SharedTopics.attach`\\ es its pool, which asks :meth:`SharedTopics.get` before it
subscribes, and is told when a shared subscription appears (:meth:`adopted`: a pooled entry
reads through it from now on) or goes (:meth:`unshared`).  Either side may start first.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol


class Consumer(Protocol):
    def adopt(self, topic: str) -> None: ...
    def unshare(self, topic: str) -> None: ...


class SharedTopics:
    """The core's one registry of shared subscriptions (ROS thread)."""

    def __init__(self) -> None:
        self.provider: Callable[[str, str | None], Any] | None = None
        self.consumer: Consumer | None = None

    def provide(self, provider: Callable[[str, str | None], Any] | None) -> None:
        """The owner's lookup (None: it shares nothing any more)."""
        self.provider = provider

    def attach(self, consumer: Consumer) -> None:
        """The reader of shared subscriptions (the data family's pool)."""
        self.consumer = consumer

    def get(self, topic: str, type_name: str | None) -> Any:
        """The shared subscription of ``topic`` (of ``type_name`` when given), or None."""
        return self.provider(topic, type_name) if self.provider is not None else None

    def adopted(self, topic: str) -> None:
        """``topic`` has a shared subscription now."""
        if self.consumer is not None:
            self.consumer.adopt(topic)

    def unshared(self, topic: str) -> None:
        """The shared subscription of ``topic`` goes."""
        if self.consumer is not None:
            self.consumer.unshare(topic)
