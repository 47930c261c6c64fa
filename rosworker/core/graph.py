"""Polling the ROS graph: change detection, pool re-checks and the ``graph`` snapshot.

rclpy in Jazzy offers no graph-change event, so the ROS thread polls every
``graph_poll_tick``: topic names and types plus node names are cheap (tens of
µs) and form a fingerprint; a changed fingerprint bumps ``generation`` and
tells the listeners (:meth:`GraphMonitor.on_change`: the data family's pool
re-checks every entry).  Between changes a listener only looks at what is cheap
(the pool: each subscription's matched-publisher count, about 1 µs), and every
second it re-checks everything, which catches what the fingerprint cannot see
(a publisher leaving a topic that our own subscription keeps in the graph).

The per-node detail the ``graph`` command returns is expensive (two calls
per node), so it is built only when asked, once per generation.

The names of the last poll (``topics``) and ``epoch`` (bumped at each full
re-check) let a stream's tick answer a topic nobody publishes without asking
the graph (``rosworker/subscriptions/registry.py``): a name that is not in ``topics`` has no
endpoint at all, and its answer only changes with ``generation``.

The ``graph`` command (``ipc/PROTOCOL.md``) answers :meth:`GraphMonitor.snapshot`;
a topic's endpoints without the gateway's own are ``core/endpoints.py``'s.
"""

from __future__ import annotations

import collections
import logging
import time
from collections.abc import Callable
from typing import Any

from ipc.errors import IpcError

from .stats import Stats
from .task import Task

log = logging.getLogger("sovd.rosworker.graph")

FULL_CHECK_EVERY = 1.0      # seconds between full re-checks (the listeners' ``full``)
SNAPSHOT_RECHECK_FOR = 10.0  # keep re-checking node detail this long after a graph request


class GraphMonitor:
    def __init__(self, node, stats: Stats):
        self.node = node
        self.stats = stats
        self._listeners: list[Callable[[bool], None]] = []
        self.own = (node.get_name(), node.get_namespace())
        # Starts from the wall clock (ms) so that a restarted worker never answers
        # "unchanged" to a generation a client cached from its predecessor.
        self.generation = time.time_ns() // 1_000_000
        self._fingerprint: int | None = None
        self._snapshot: dict[str, Any] | None = None
        self._last_full = 0.0
        self._last_request = 0.0
        self.nodes: list[str] = []  # fully qualified names of the other nodes, as of the last change
        self.topics: frozenset[str] = frozenset()  # topic names of the graph, as of the last change
        self.epoch = 0  # bumped at every full re-check (a change, or FULL_CHECK_EVERY)

    def tick(self) -> None:
        names_types = self.node.get_topic_names_and_types()
        nodes = self.node.get_node_names_and_namespaces()
        fingerprint = hash((tuple((n, tuple(t)) for n, t in names_types), tuple(sorted(nodes))))
        now = time.monotonic()
        changed = fingerprint != self._fingerprint
        if changed:
            self._fingerprint = fingerprint
            self.nodes = node_names(nodes, self.own)
            self.topics = frozenset(n for n, _ in names_types)
            self._bump()
        full = changed or now - self._last_full >= FULL_CHECK_EVERY
        if full:
            self._last_full = now
            self.epoch += 1
        for listener in self._listeners:
            listener(full)
        if full and not changed and self._snapshot is not None \
                and now - self._last_request < SNAPSHOT_RECHECK_FOR:
            # Endpoint changes that leave names and types alone (a node adds a
            # subscription to an existing topic) only show in the detail.
            fresh = self._build()
            if fresh.pop("complete") and _comparable(fresh) != _comparable(self._snapshot):
                self._bump()
                fresh["generation"] = self.generation
                self._snapshot = fresh

    def on_change(self, listener: Callable[[bool], None]) -> None:
        """``listener(full)`` after every poll: ``full`` when the graph changed or at the periodic full
        re-check (everything is looked at again then; only what is cheap otherwise).  ROS thread."""
        self._listeners.append(listener)

    def command(self, task: Task) -> None:
        """``graph`` (``since``: the generation the caller has; "unchanged" when it is still the one)."""
        since = task.args.get("since")
        if since is not None and (isinstance(since, bool) or not isinstance(since, int)):
            raise IpcError("bad-request", "since: expected an integer generation")
        task.reply(self.snapshot(since))

    def _bump(self) -> None:
        self.generation += 1
        self.stats.graph_events_received += 1
        self._snapshot = None

    def snapshot(self, since: int | None = None) -> dict[str, Any]:
        self._last_request = time.monotonic()
        if since is not None and since == self.generation and self._snapshot is not None:
            return {"generation": self.generation, "unchanged": True}
        if self._snapshot is None:
            snapshot = self._build()
            if snapshot.pop("complete"):
                self._snapshot = snapshot  # an incomplete one is rebuilt on the next request
            return snapshot
        return self._snapshot

    def _build(self) -> dict[str, Any]:
        own_pubs: collections.Counter = collections.Counter()
        own_subs: collections.Counter = collections.Counter()
        nodes = []
        complete = True
        for name, namespace in sorted(self.node.get_node_names_and_namespaces(), key=lambda x: (x[1], x[0])):
            try:
                pubs = self.node.get_publisher_names_and_types_by_node(name, namespace)
                subs = self.node.get_subscriber_names_and_types_by_node(name, namespace)
            except Exception:  # the node left between the two calls, or is half discovered
                # Listed without its topics for now (an app that is running must never
                # answer 404); the snapshot is not kept, so the next request asks again.
                complete = False
                pubs, subs = [], []
            if (name, namespace) == self.own:
                own_pubs.update(t for t, _ in pubs)
                own_subs.update(t for t, _ in subs)
                continue
            fqn = (namespace.rstrip("/") + "/" + name) if namespace != "/" else "/" + name
            nodes.append({
                "name": name, "namespace": namespace, "fqn": fqn,
                "publishes": [[t, types[0]] for t, types in sorted(pubs) if types],
                "subscribes": [[t, types[0]] for t, types in sorted(subs) if types],
            })
        topics = []
        for name, types in sorted(self.node.get_topic_names_and_types()):
            pubs = max(0, self.node.count_publishers(name) - own_pubs[name])
            subs = max(0, self.node.count_subscribers(name) - own_subs[name])
            if pubs or subs:
                topics.append({"name": name, "types": list(types), "publisher_count": pubs,
                               "subscriber_count": subs})
        return {"generation": self.generation, "unchanged": False, "nodes": nodes, "topics": topics,
                "complete": complete}


def node_names(nodes: list[tuple[str, str]], own: tuple[str, str]) -> list[str]:
    """Fully qualified names of ``(name, namespace)`` pairs, without our own node."""
    return sorted((ns.rstrip("/") + "/" + name) for name, ns in nodes if (name, ns) != own)


def _comparable(snapshot: dict[str, Any]) -> Any:
    return (snapshot["nodes"], [(t["name"], t["types"]) for t in snapshot["topics"]])


def settle(node, expected: set[str], least: float, quiet: float, most: float,
           stop: Callable[[], bool] = lambda: False) -> None:
    """Wait until DDS discovery has found the running graph, before the worker answers anyone.

    A graph answered too early would tell the HTTP side that nodes which never left are gone
    (404).  Until the socket is bound, clients get 503 ``unavailable`` with Retry-After instead,
    which is the truth.  Settled means: the nodes the previous worker knew (``expected``) are back,
    or ``most`` seconds passed (some of them really left); at least ``least`` seconds passed; and
    the graph has not changed for ``quiet``.  At the first boot nobody was told anything before, so
    only the quiet period counts (gunicorn, started next, takes longer to answer anyway).
    """
    own = (node.get_name(), node.get_namespace())
    started = time.monotonic()
    last, quiet_since = None, started
    while not stop():
        now = time.monotonic()
        nodes = node.get_node_names_and_namespaces()
        seen = (sorted(nodes), sorted((n, tuple(t)) for n, t in node.get_topic_names_and_types()))
        if seen != last:
            last, quiet_since = seen, now
        elapsed = now - started
        found = expected.issubset(node_names(nodes, own))
        if elapsed >= most or (found and elapsed >= least and now - quiet_since >= quiet):
            break
        time.sleep(0.05)
    log.info("discovery settled after %.2f s (%d nodes)", time.monotonic() - started, len(last[0]) if last else 0)
