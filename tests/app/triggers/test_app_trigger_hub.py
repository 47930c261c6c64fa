"""app/triggers/hub.py on a real events socket: a hub receives the frames of the groups its streams watch, only
those, and pushes one change into the streams of each trigger it fired.

The ROS worker's side is a thread with an XPUB that confirms each subscription as rosworker/core/events.py does;
the hub is the real one (its SUB socket, reader greenlet and streams), without a gateway around it.  The same
through a real gateway and real publishers: tests/system/triggers/test_app_trigger_fanout.py.
"""

from __future__ import annotations

import queue
import threading

import gevent
import zmq as plain_zmq

from app.triggers.hub import TriggerHub
from ipc import events, protocol
from ipc.server import bind_publisher

A, B, C = "trig_000000000000000a", "trig_000000000000000b", "trig_000000000000000c"
WATCHED = events.trigger_group_key("data", "array", "/watched")
ELSEWHERE = events.trigger_group_key("data", "array", "/elsewhere")
IN_BASE64 = events.trigger_group_key("data", "base64", "/watched")


def test_a_hub_gets_only_its_groups_frames_and_frames_each_change_once_for_the_streams_it_fired(tmp_path):
    zctx = plain_zmq.Context()
    pub = bind_publisher(zctx, str(tmp_path))
    outbox: queue.Queue[list[bytes]] = queue.Queue()
    stop = threading.Event()

    def ros_worker() -> None:
        while not stop.is_set():
            if pub.poll(10) and (message := pub.recv())[:1] == b"\x01":
                pub.send_multipart([message[1:]])  # the confirmation
            while not outbox.empty():
                pub.send_multipart(outbox.get())

    thread = threading.Thread(target=ros_worker, daemon=True)
    thread.start()
    hub = TriggerHub(str(tmp_path), lambda stream, opening: {"id": stream.id, "status": "active"})
    seen: list[bytes] = []
    dispatch = hub.dispatch
    hub.dispatch = lambda frames: (len(frames) > 1 and seen.append(frames[0]), dispatch(frames))  # not confirmations
    hub.start()
    bodies = []
    try:
        streams = {}
        for trigger_id in (A, A, B):  # two streams of A, one of B: all of one group
            stream = hub.stream({"id": trigger_id, "collection": "apps", "entity_id": "x", "source": "data",
                                 "bytes": "array", "target": "/watched"})
            body = stream.body(hub.opening)
            assert next(body) == b""  # opened: its subscription confirmed
            bodies.append(body)
            streams.setdefault(trigger_id, []).append(stream)
        assert set(hub.by_key) == {WATCHED}

        def fired(key: bytes, stamp: int, entries: list, payload: bytes) -> None:
            outbox.put([key, protocol.pack({"ts": stamp, "fired": entries}), payload])

        fired(ELSEWHERE, 1, [[A, 5, False]], b'{"n":1}')     # another topic: never reaches this process
        fired(IN_BASE64, 2, [[C, 5, False]], b'{"n":2}')     # the other bytes mode of the topic: neither
        fired(WATCHED, 3, [[C, 7, False]], b'{"n":3}')       # this group, no trigger of this process: passed over
        fired(WATCHED, 4, [[A, 8, False], [B, 9, True], [C, 8, False]], b'{"n":4}')  # B a one-shot
        with gevent.Timeout(5):
            while seen.count(WATCHED) < 2:
                gevent.sleep(0.01)
        # Frames of one socket arrive in order: had the first two been let through, they would be here already.
        assert [key for key in seen if key.startswith(events.TRIGGER_GROUP_PREFIX)] == [WATCHED, WATCHED]
        frame = b'data: {"timestamp":"1970-01-01T00:00:00.000Z","payload":{"n":4}}\n\n'
        for stream in (*streams[A], *streams[B]):
            assert list(stream.frames) == [frame] and stream.last_seq in (8, 9)
        assert len({id(s.frames[0]) for s in (*streams[A], *streams[B])}) == 1  # one buffer for every stream
        assert streams[B][0].ended and not any(s.ended for s in streams[A])
    finally:
        for body in bodies:
            body.close()
        hub.stop()
        stop.set()
        thread.join(5)
        pub.close()
        zctx.term()
