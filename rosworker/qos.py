"""Subscriber QoS matched to the publishers of a topic (architecture.md's rules).

- depth: keep_last 1 always: the pool only ever serves the newest message.
- durability: TransientLocal if any publisher is TransientLocal (a latched
  value published long before the first read must be served), else Volatile.
- reliability: Reliable only if *every* publisher is Reliable, else
  BestEffort.  A reliable reader cannot match a best-effort writer, while a
  best-effort reader hears both.
- deadline and liveliness: never stricter than what every publisher offers;
  we request the defaults (infinite deadline, automatic liveliness, infinite
  lease), which every publisher satisfies.
"""

from __future__ import annotations

from collections.abc import Iterable

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy


def match_qos(publishers: Iterable) -> QoSProfile:
    """``publishers``: ``TopicEndpointInfo`` objects from ``get_publishers_info_by_topic``."""
    profiles = [p.qos_profile for p in publishers]
    reliable = bool(profiles) and all(q.reliability == ReliabilityPolicy.RELIABLE for q in profiles)
    latched = any(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in profiles)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


def describe(qos: QoSProfile) -> str:
    return f"{qos.reliability.name.lower()}/{qos.durability.name.lower()}/depth{qos.depth}"


def key(qos: QoSProfile) -> tuple:
    return (qos.reliability, qos.durability, qos.depth)
