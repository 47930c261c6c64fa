"""``make bench``: side-by-side performance of the gateway against its floor and the old design.

``python -m bench.run`` (see :mod:`bench.run`) starts its own ROS publishers
and a real ``sovd-gateway`` in a private ROS domain, measures every case of
the table, prints it and writes it as JSON under ``bench/results/``.

Its ROS programs live beside the tests' own, in ``tests/support/`` (only
``rosworker/`` of the gateway may create ROS entities), each run as its own process:

- :mod:`tests.support.benchpub` — publishers: many topics per node, one timer per rate;
- :mod:`tests.support.oldsampler` — the old subscribe-per-request design, in rclpy;
- :mod:`tests.support.ddsfloor` — a bare rclpy process holding subscriptions without spinning.

and, beside the gateway, :mod:`tests.support.echoworker`: the process behind the
echo route (``--debug-commands``), the pure IPC hop the warm sample is compared with.

Helpers of its own:

- :mod:`bench.load` — ``wrk`` (or the Python fallback) and the 1-connection latency client;
- :mod:`bench.procs` — helper processes and CPU figures (the rest comes from ``tests/support``).
"""
