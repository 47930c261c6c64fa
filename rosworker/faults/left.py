"""Faults left by nodes that are not on the graph: loaded from the fault store, nobody reports them.

The fault store (``store.py``) outlives the gateway, and every gateway of a user or a robot
that shares a state directory opens the same ``faults.db``.  A fault loaded from it whose nodes
are not on this gateway's graph is one nobody will report again: an earlier run's, another
robot's, a node that died.  Each such fault goes stale (CRITICAL) after ``fault_stale_s`` and
stays active until it is cleared, which looks like a new failure of this robot.  So the gateway
says so:

- once, ``check_after`` seconds after the start (discovery has settled by then), a warning in
  its log that names the store, counts the faults, names their nodes and says what to do;
- for as long as it holds, ``/health``'s ``x-medkit-faults``: ``left_by_absent_nodes`` (how
  many) and ``absent_nodes`` (their reporting nodes, at most ``NODES_SHOWN``), which the
  dashboard shows above its faults.

A loaded fault counts while it is active (pending or confirmed) and none of its reporting
sources is a node on the graph.  It stops counting once one of its nodes shows up (and reports
again), and once it heals or is cleared.  A fault first seen by this ROS worker never counts: a
node that dies now leaves a stale fault that is this robot's own failure.  A fault whose only
source is ``/diagnostics`` (its node was never known) is not counted either.
"""

from __future__ import annotations

import logging
from typing import Any

from .model import ACTIVE, TOPIC

log = logging.getLogger("sovd.rosworker.faults")

CHECK_EVERY = 1.0   # seconds between two checks
NODES_SHOWN = 16    # nodes named in /health and in the log line


def check_delay(stale_s: float) -> float:
    """When to look first: when the loaded faults would go stale (``fault_stale_s``; 10 s when
    that is off), at least 5 s (discovery settles) and at most 30 s after the start."""
    return min(max(stale_s or 10.0, 5.0), 30.0)


class LeftFaults:
    """The loaded faults whose nodes are absent (see the module docstring); runs on the ROS thread."""

    def __init__(self, manager, graph, stats, executor, check_after: float):
        self.manager = manager
        self.graph = graph
        self.stats = stats
        self.executor = executor
        self.check_after = check_after
        self.loaded = {code for code, record in manager.faults.items() if record["status"] in ACTIVE}
        self.warned = False

    def start(self) -> None:
        if self.loaded:
            self.executor.call_later(self.check_after, self._round)

    def _round(self) -> None:
        self.check()
        if self.loaded:
            self.executor.call_later(CHECK_EVERY, self._round)

    def absent(self) -> tuple[list[str], list[str]]:
        """(the codes of the loaded faults whose nodes are absent, those nodes), sorted."""
        present = set(self.graph.nodes)
        codes, nodes = [], set()
        for code in sorted(self.loaded):
            record: dict[str, Any] | None = self.manager.faults.get(code)
            if record is None or record["status"] not in ACTIVE:
                self.loaded.discard(code)   # healed, cleared or dropped: it never counts again
                continue
            sources = [s for s in record["sources"] if s != TOPIC]
            if sources and not present.intersection(sources):
                codes.append(code)
                nodes.update(sources)
        return codes, sorted(nodes)

    def check(self) -> None:
        codes, nodes = self.absent()
        left = {"left_by_absent_nodes": len(codes), "absent_nodes": nodes[:NODES_SHOWN]}
        if left != self.manager.left:
            self.manager.left = left
            self.manager.publish_stats()
        if codes and not self.warned:
            self.warned = True
            more = f" and {len(nodes) - NODES_SHOWN} more" if len(nodes) > NODES_SHOWN else ""
            one = len(codes) == 1
            log.warning(
                "faults: %d active fault%s loaded from %s %s reported by %s not on the ROS graph %.0f s "
                "after the start (%s%s): left by an earlier run or another robot, or %s died. Nobody reports "
                "%s, so %s stale (CRITICAL) and %s active. Clear %s (DELETE /api/v1/faults, with "
                "--allow-fault-clear), or give this gateway a state directory of its own (--state-dir). "
                "/health shows %s as x-medkit-faults.left_by_absent_nodes.",
                len(codes), "" if one else "s", self.manager.store.path, "was" if one else "were",
                "a node that is" if len(nodes) == 1 else "nodes that are", self.check_after,
                ", ".join(nodes[:NODES_SHOWN]), more, "its node" if len(nodes) == 1 else "their nodes",
                "it" if one else "them", "it goes" if one else "they go", "stays" if one else "stay",
                "it" if one else "them", "it" if one else "them")
