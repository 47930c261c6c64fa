"""The fleet over Zenoh (issue 34): the fleet-link process and what it speaks.

A robot's gateway with ``fleet_link`` on runs ``sovd-fleetlink`` beside its
ROS worker; the fleet gateway (``fleet_aggregate``) runs it instead of a ROS
worker.  Only this process holds a Zenoh session: never an HTTP worker, never
the ROS worker.  ``docs/fleet.md`` is the operator's account;
``supervisor/fleet/PROTOCOL.md`` the wire's.
"""
