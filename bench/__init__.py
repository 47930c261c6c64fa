"""``make bench``: side-by-side performance of the gateway against its floor and the old design.

``python -m bench.run`` (see :mod:`bench.run`) starts its own ROS publishers
and a real ``sovd-gateway`` in a private ROS domain, measures every case of
the table, prints it and writes it as JSON under ``bench/results/``.

Its ROS programs live here, in ``bench/`` (exempt, like ``tests/`` and ``demo/``, from the rule
that only ``rosworker/`` creates ROS entities: tests/test_layout.py), each run as its own process:

- :mod:`bench.benchpub` — publishers: many topics per node, one timer per rate;
- :mod:`bench.oldsampler` — the old subscribe-per-request design, in rclpy;
- :mod:`bench.ddsfloor` — a bare rclpy process holding subscriptions without spinning.

and, beside the gateway, :mod:`bench.echoworker`: the process behind the
echo route (``--debug-commands``), the pure IPC hop the warm sample is compared with;
:mod:`bench.sseload` reads event streams (also for ``tests/reliability/test_streams.py``).

Helpers of its own:

- :mod:`bench.load` — ``wrk`` (or the Python fallback) and the 1-connection latency client;
- :mod:`bench.procs` — helper processes and CPU figures.

What it shares with the tests and the demo is common/harness/ (:mod:`common.harness`): the private
ROS domain, processes, the gateway, ``rosmain`` (what every ROS program here starts and spins with),
the ``/diagnostics`` and ``/rosout`` nodes, the simulated fleet.  It imports nothing from ``tests/``
(tests/test_layout.py).
"""
