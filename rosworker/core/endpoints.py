"""A topic's endpoints as the graph lists them, the gateway's own node left out.

The gateway's own endpoints (its pooled subscriptions, its publishers for PUT,
its trigger subscriptions) never count as a topic's publishers or subscribers:
the pool, the publishers, the triggers and the faults count and type topics by
:class:`Endpoints`.  ROS thread only.
"""

from __future__ import annotations


class Endpoints:
    """A topic's endpoints as the graph lists them, the gateway's own node left out (ROS thread)."""

    def __init__(self, node):
        self.node = node
        self.own = (node.get_name(), node.get_namespace())

    def _foreign(self, infos: list) -> list:
        own_name, own_ns = self.own
        return [i for i in infos if i.node_name != own_name or i.node_namespace != own_ns]

    def publishers(self, topic: str) -> list:
        """``TopicEndpointInfo`` of the topic's publishers, the gateway's own left out."""
        return self._foreign(self.node.get_publishers_info_by_topic(topic))

    def subscribers(self, topic: str) -> list:
        """``TopicEndpointInfo`` of the topic's subscribers, the gateway's own left out."""
        return self._foreign(self.node.get_subscriptions_info_by_topic(topic))

    def subscriber_count(self, topic: str) -> int:
        return len(self.subscribers(topic))
