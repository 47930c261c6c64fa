"""An app dropped without closing frees its ZeroMQ context by reference counting, sockets first.

Left to the cyclic collector, the context may be finalized before its sockets, and its
``term()`` then blocks for ever (pyzmq's ``Context.__del__``): a test run hung for minutes.
"""

from __future__ import annotations

import gc
import weakref

from app.core import rosclient
from app.sse import hub as sse
from tests.support.fakeworker import make_app


def test_an_unclosed_app_is_freed_without_the_cyclic_collector(tmp_path):
    app = make_app(runtime_dir=str(tmp_path), rate_limit="100/100")
    client = app.test_client()
    assert client.get("/api/v1/health").status_code == 200  # a call: the context and sockets exist
    ros = app.extensions[rosclient.EXTENSION].client
    assert ros.channel_count >= 1
    alive = [weakref.ref(x) for x in (ros, app.extensions[sse.EXTENSION]["subscriptions"])]
    gc.disable()
    try:
        del app, client, ros
        assert [ref() for ref in alive] == [None, None]
    finally:
        gc.enable()
