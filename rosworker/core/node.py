"""The gateway's rclpy node: an entity leaves the waiter's wait set before it is destroyed.

Every family destroys what it made through the node (``destroy_subscription``,
``destroy_client``, :meth:`GatewayNode.destroy_action_client`), so the rule of
``waiter.py`` (no entity is destroyed while it is waited on) holds in one place.
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.node import Node


class GatewayNode(Node):
    """``rclpy.node.Node`` whose destroys first call :attr:`releasing` with the entity (ROS thread)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.releasing: Callable[[object], None] = lambda entity: None

    def destroy_subscription(self, subscription) -> bool:
        self.releasing(subscription)
        return super().destroy_subscription(subscription)

    def destroy_client(self, client) -> bool:
        self.releasing(client)
        return super().destroy_client(client)

    def destroy_action_client(self, client) -> None:
        """``rclpy.action.ActionClient.destroy`` after :attr:`releasing`."""
        self.releasing(client)
        client.destroy()
