"""Which node reported a status: the reporting source of a fault (``manager.py``).

The source is the ``hardware_id`` when it contains ``/`` (a node name,
medkit's ``use_hardware_id_as_source_id``); else the node whose name starts
the status name (``diagnostic_updater`` names statuses ``<node name>: <task>``);
else, as a guess, the only node that publishes ``/diagnostics`` (one whose name
discovery does not know yet is no node); else ``/diagnostics`` itself (rclpy
does not say which publisher sent a message).  A name the graph monitor's last
poll does not know is asked of the graph directly (at most every
``GRAPH_RETRY`` s): a driver that just started.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from .model import CODE_MAX, TOPIC

PUBLISHERS_TTL = 1.0       # seconds the publishers of /diagnostics are cached
GRAPH_RETRY = 0.1          # seconds between two direct graph queries for a status's unknown node


class Attribution:
    """The reporting source of a status (ROS thread)."""

    def __init__(self, node: Any, graph: Any, endpoints: Any):
        self.node = node
        self.graph = graph
        self.endpoints = endpoints
        self._publishers: tuple[float, list[str]] = (0.0, [])
        self._graph_asked = -GRAPH_RETRY
        self._fresh_nodes: list[str] = []

    def source(self, status) -> tuple[str, bool]:
        """``(source, guessed)``: the node the status names (its hardware_id, or the node its name
        starts with), else a guess (the only publisher of /diagnostics, or the topic itself)."""
        return self.source_of(status.name, status.hardware_id, self._only_publisher)

    def source_of(self, name: str, hardware_id: str, guess: Callable[[], str]) -> tuple[str, bool]:
        if "/" in hardware_id:
            return hardware_id[:CODE_MAX], False
        prefix, sep, _ = name.partition(":")
        if sep and prefix.strip():
            matches = self._nodes_named(prefix.strip())
            if len(matches) == 1:
                return matches[0], False
        return guess(), True

    def _only_publisher(self) -> str:
        publishers = self._diagnostics_publishers()
        return publishers[0] if len(publishers) == 1 else TOPIC

    def _nodes_named(self, name: str) -> list[str]:
        """The graph's nodes called ``name``; asked again (at most every GRAPH_RETRY s) on a miss,
        since the graph monitor's last poll may predate a driver that just started."""
        nodes = list(self.graph.nodes) if self.graph is not None else []
        matches = [n for n in nodes if n.rsplit("/", 1)[-1] == name]
        now = time.monotonic()
        if not matches and self.node is not None and now - self._graph_asked >= GRAPH_RETRY:
            self._graph_asked = now
            self._publishers = (0.0, [])   # the publishers of /diagnostics are asked again too
            fresh = [(ns.rstrip("/") + "/" + n) for n, ns in self.node.get_node_names_and_namespaces()]
            self._fresh_nodes = fresh
        if not matches:
            matches = [n for n in self._fresh_nodes if n.rsplit("/", 1)[-1] == name]
        return matches

    def _diagnostics_publishers(self) -> list[str]:
        when, names = self._publishers
        now = time.monotonic()
        if now - when >= PUBLISHERS_TTL and self.endpoints is not None:
            infos = self.endpoints.publishers(TOPIC)
            # An endpoint found before its node is named "_NODE_NAME_UNKNOWN_": no node, no source.
            names = sorted({(i.node_namespace.rstrip("/") + "/" + i.node_name) for i in infos
                            if not i.node_name.startswith("_NODE_NAME_UNKNOWN")})
            self._publishers = (now, names)
        return names
