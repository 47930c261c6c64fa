"""The process harness that the tests, the bench and the demo share (neither owns it).

- :mod:`.procs` — a private ROS domain, child processes with deadlines, :func:`~.procs.poll_until`;
- :mod:`.gateway` — ``sovd-gateway`` started as an operator starts it (:class:`~.gateway.Gateway`);
- :mod:`.rosmain` — what every ROS program run with ``-m`` shares: start a node, spin it, stop on SIGTERM;
- ROS and Zenoh programs that the tests and the bench both run, each with the class that starts it:
  :mod:`.diagpub` (``/diagnostics``), :mod:`.roslogger` (``/rosout``), :mod:`.fleetsim` (simulated
  robots of the fleet); :mod:`.fibonacci`, the goal loop of a Fibonacci action server (the demo's and
  the tests').

No module of the gateway (app/, rosworker/, ipc/, supervisor/, the rest of common/) imports it
(tests/test_layout.py), so common/'s own rules (no rclpy, no zenoh, nothing of ours imported) do not
bind it: it starts, and talks to, the gateway's processes from outside.
"""
