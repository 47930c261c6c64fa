"""``make bench``: side-by-side performance of the gateway against its floor and the old design.

``python -m bench.run`` (see :mod:`bench.run`) starts its own ROS publishers
and a real ``sovd-gateway`` in a private ROS domain, measures every case of
the table, prints it and writes it as JSON under ``bench/results/``.

Helpers, each its own process where the case needs one:

- :mod:`bench.robot` — publishers: many topics per node, one timer per rate;
- :mod:`bench.oldsampler` — the old subscribe-per-request design, in rclpy;
- :mod:`bench.ddsfloor` — a bare rclpy process holding subscriptions without spinning;
- :mod:`bench.load` — ``wrk`` (or the Python fallback) and the 1-connection latency client.
"""
