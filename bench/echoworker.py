"""The bench's pure-hop reference: a ZeroMQ ROUTER that answers every request at once.

    python -m bench.echoworker ENDPOINT

It binds ``ENDPOINT`` (``app/core/debug.py``: ``ipc://<runtime_dir>/bench-echo.sock``)
and answers each request of ``ipc/PROTOCOL.md``'s envelope with
``{"v", "id", "ok": true, "result": <the request's args>}``, on one thread, with
no work in between: what is left of a round trip through the gateway's HTTP
stack and IPC client once the ROS worker's own work is taken away.  Prints
``READY`` once bound; stops on SIGTERM or SIGINT.
"""

from __future__ import annotations

import signal
import sys

import zmq

from ipc import protocol

POLL_MS = 200


def main(argv: list[str]) -> int:
    endpoint = argv[0]
    stop: list[int] = []
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda signum, frame: stop.append(signum))
    ctx = zmq.Context()
    sock = ctx.socket(zmq.ROUTER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.bind(endpoint)
    print("READY", flush=True)
    try:
        while not stop:
            if not sock.poll(POLL_MS):
                continue
            peer, frame = sock.recv_multipart()
            try:
                request = protocol.unpack(frame, protocol.MAX_FRAME)
            except ValueError:
                continue
            sock.send_multipart([peer, protocol.pack({"v": protocol.VERSION, "id": request.get("id"),
                                                      "ok": True, "result": request.get("args", {})})])
    finally:
        sock.close(linger=0)
        ctx.term()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
