"""app/sse/channel.py: an event stream waits for the ROS worker's confirmation of its subscription.

The confirmations on their own (greenlets, no socket), then through a real
ZeroMQ events socket confirmed as the ROS worker does: an event sent right
after the wait returned always arrives.
"""

from __future__ import annotations

import threading

import gevent
import zmq as plain_zmq
import zmq.green as zmq

from app.sse import channel
from ipc import events
from ipc.server import bind_publisher

KEY = events.trigger_group_key("data", "array", "/channel")


def test_a_wait_returns_once_the_key_is_seen_and_not_before():
    confirmations = channel.Confirmations()
    confirmations.expect(KEY)
    waiter = gevent.spawn(confirmations.wait, KEY, timeout=5)
    gevent.sleep(0.05)
    assert not waiter.ready()  # nothing seen yet: the stream does not open
    confirmations.seen(events.trigger_group_key("data", "base64", "/channel"))  # another key's message is no confirmation
    gevent.sleep(0.05)
    assert not waiter.ready()
    confirmations.seen(KEY)
    assert waiter.get(timeout=5) is True
    assert confirmations.wait(KEY, timeout=0) is True  # confirmed once: later streams do not wait


def test_a_lost_connection_needs_a_new_confirmation_and_a_missing_one_times_out():
    confirmations = channel.Confirmations()
    confirmations.expect(KEY)
    confirmations.seen(KEY)
    confirmations.lost()
    assert confirmations.wait(KEY, timeout=0.05) is False
    assert confirmations.late == 1
    confirmations.forget(KEY)  # unsubscribed: nothing to wait for
    assert confirmations.wait(KEY, timeout=0) is True


def test_an_event_sent_right_after_the_confirmation_arrives(tmp_path):
    """The ROS worker's side in a thread (an XPUB confirming each subscription as rosworker/subscriptions/registry.py
    does, then the event at once); the HTTP worker's side a green SUB that waits as a stream does."""
    zctx = plain_zmq.Context()
    pub = bind_publisher(zctx, str(tmp_path))
    stop = threading.Event()

    def ros_worker() -> None:
        while not stop.is_set():
            if pub.poll(50):
                message = pub.recv()
                if message[:1] == b"\x01":
                    pub.send_multipart([message[1:]])           # the confirmation
                    pub.send_multipart([message[1:], b"meta", b"{}"])  # an event, at once

    thread = threading.Thread(target=ros_worker, daemon=True)
    thread.start()
    ctx = zmq.Context()
    try:
        sock = channel.subscriber(ctx)
        sock.connect(events.endpoint(str(tmp_path)))
        confirmations = channel.Confirmations()
        confirmations.expect(KEY)
        sock.setsockopt(zmq.SUBSCRIBE, KEY)
        got: list[list[bytes]] = []

        def read() -> None:
            while True:
                frames = sock.recv_multipart()
                confirmations.seen(frames[0])
                if len(frames) > 1:
                    got.append(frames)

        reader = gevent.spawn(read)
        assert confirmations.wait(KEY, timeout=5)
        with gevent.Timeout(5):
            while not got:
                gevent.sleep(0.01)
        assert got == [[KEY, b"meta", b"{}"]]
        reader.kill()
        sock.close()
    finally:
        stop.set()
        thread.join(5)
        pub.close()
        ctx.term()
        zctx.term()
