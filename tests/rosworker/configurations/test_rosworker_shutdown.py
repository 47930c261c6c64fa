"""A ROS worker told to stop answers what is in flight: parameter calls get the shutdown error.

A parameter operation waits on another node's services; a SIGTERM that comes meanwhile must answer
it with ``shutdown`` (503 ``x-medkit-gateway-shutdown`` on the HTTP side) before the worker exits,
not leave its caller to run into its own deadline.
"""

from __future__ import annotations

import json
import signal
import sys
import threading
import time

from common.harness.procs import Proc, poll_until
from ipc.errors import IpcError
from tests.support.rosworker import RosWorker

CALLS = 3
NODE_TIMEOUT = 20.0   # --parameter-service-timeout: far past the test's wait, so only shutdown answers
CALL_TIMEOUT = 40.0   # the callers' own deadline


def test_sigterm_answers_parameter_calls_in_flight_with_the_shutdown_error():
    hung = Proc([sys.executable, "-m", "tests.support.paramnode",
                 json.dumps({"node": "hung", "namespace": "/shutdown", "hang": True,
                             "params": [{"name": "x", "value": 1}]})], name="paramnode hung")
    worker = None
    try:
        hung.wait_line(lambda line: line == "READY", 30)
        worker = RosWorker(parameter_service_timeout=NODE_TIMEOUT)
        # The node in the worker's graph first (a node it does not know is answered at once).
        poll_until(lambda: any(n["fqn"] == "/shutdown/hung" for n in worker.call("graph")["nodes"]), 30,
                   message="the hung node in the graph")
        answers: list = [None] * CALLS

        def call(i: int) -> None:
            started = time.monotonic()
            try:
                worker.call("param_get", {"node": "/shutdown/hung", "name": "x"}, timeout=CALL_TIMEOUT)
                answers[i] = ("answered", time.monotonic() - started)
            except IpcError as exc:
                answers[i] = (exc.code, time.monotonic() - started)

        threads = [threading.Thread(target=call, args=(i,), daemon=True) for i in range(CALLS)]
        for thread in threads:
            thread.start()
        # All in flight: each waits on the hung node (its services are matched, it never answers).
        poll_until(lambda: worker.stats()["details"]["parameter_calls_in_flight"] == CALLS
                   or any(a is not None for a in answers), 30, message="the parameter calls in flight")
        assert answers == [None] * CALLS, answers
        worker.proc.send_signal(signal.SIGTERM)
        for thread in threads:
            thread.join(CALL_TIMEOUT + 5)
        assert worker.proc.wait(15) == 0
        assert [a[0] for a in answers] == ["shutdown"] * CALLS, answers
        assert all(a[1] < NODE_TIMEOUT for a in answers), answers  # answered at the signal, not at a deadline
    finally:
        if worker is not None:
            worker.stop()
        hung.stop()
