"""QoS matched to the other side of a topic (README "How it works"; the rules below).

Our subscriptions (the pool), matched to the topic's publishers:

- depth: keep_last 1 always: the pool only ever serves the newest message.
- durability: TransientLocal if any publisher is TransientLocal (a latched
  value published long before the first read must be served), else Volatile.
- reliability: Reliable only if *every* publisher is Reliable, else
  BestEffort.  A reliable reader cannot match a best-effort writer, while a
  best-effort reader hears both.
- deadline and liveliness: never stricter than what every publisher offers;
  we request the defaults (infinite deadline, automatic liveliness, infinite
  lease), which every publisher satisfies.

Our publishers (``PUT``), matched to the topic's subscribers by DDS's
request-versus-offered rules, so that every subscriber can hear them:

- reliability: Reliable always (a reliable writer matches reliable and
  best-effort readers alike);
- durability: TransientLocal if any subscriber is TransientLocal (a latched
  command input only matches a transient-local writer; it matches volatile
  readers too), else Volatile; depth 1 then (a late joiner gets the newest
  command only), else 10;
- deadline: the shortest any subscriber requests (an offered deadline must
  not be longer than a requested one), else none;
- liveliness: the strictest kind any subscriber requests (manual-by-topic
  over automatic) with the shortest lease; publishing asserts it.
"""

from __future__ import annotations

from collections.abc import Iterable

from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

INFINITE_NS = 2**63 - 1   # how rmw reports an infinite duration


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


def _finite_ns(duration: Duration) -> int | None:
    ns = duration.nanoseconds
    return ns if 0 < ns < INFINITE_NS else None


def publisher_qos(subscribers: Iterable) -> QoSProfile:
    """``subscribers``: ``TopicEndpointInfo`` objects from ``get_subscriptions_info_by_topic``."""
    profiles = [s.qos_profile for s in subscribers]
    latched = any(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in profiles)
    deadlines = [ns for q in profiles if (ns := _finite_ns(q.deadline)) is not None]
    manual = [q for q in profiles if q.liveliness == LivelinessPolicy.MANUAL_BY_TOPIC]
    leases = [ns for q in profiles if (ns := _finite_ns(q.liveliness_lease_duration)) is not None]
    profile = QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=1 if latched else 10,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
        liveliness=LivelinessPolicy.MANUAL_BY_TOPIC if manual else LivelinessPolicy.AUTOMATIC,
    )
    if deadlines:
        profile.deadline = Duration(nanoseconds=min(deadlines))
    if leases:
        profile.liveliness_lease_duration = Duration(nanoseconds=min(leases))
    return profile


def hears(subscription: QoSProfile, publisher: QoSProfile) -> bool:
    """Whether a subscription with this QoS matches a publisher with that one (durability and reliability)."""
    if subscription.durability == DurabilityPolicy.TRANSIENT_LOCAL \
            and publisher.durability != DurabilityPolicy.TRANSIENT_LOCAL:
        return False
    return not (subscription.reliability == ReliabilityPolicy.RELIABLE
                and publisher.reliability != ReliabilityPolicy.RELIABLE)


def describe(qos: QoSProfile) -> str:
    return f"{qos.reliability.name.lower()}/{qos.durability.name.lower()}/depth{qos.depth}"


def key(qos: QoSProfile) -> tuple:
    return (qos.reliability, qos.durability, qos.depth, qos.deadline.nanoseconds, qos.liveliness,
            qos.liveliness_lease_duration.nanoseconds)
