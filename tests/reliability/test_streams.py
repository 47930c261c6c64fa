"""Scenario: many live streams at once (cyclic subscriptions over SSE), then all of them gone.

Short form (``make test``): 300 streams for 10 s; long form (``make
reliability``): the full 1,000 for 30 s.  10 topics at ``normal`` (5 frames/s
each), read by two client processes (``bench/sseload.py``), while a
probe polls ``/health``.

Nothing may crash or hang: every stream opens and gets its frames (a
generous share: delivery and lateness targets are the bench's), ``/health``
keeps answering, the ROS worker is never restarted, and once the clients are
gone every stream is given back (``open_streams`` 0) and the HTTP workers'
memory is what it was give or take.
"""

from __future__ import annotations

from common.harness.procs import poll_until
from tests.reliability import streams
from tests.reliability.load import HealthProbe, memory, record, restarts_in, scaled

STREAMS = scaled(300, 1000)
SECONDS = scaled(10, 30)
TOPICS = [f"/streams/t{i}" for i in range(10)]
APP = "stream_pubs"


def test_many_streams_hold_and_are_all_given_back(gateways, nodes):
    nodes.append(streams.publishers(APP, TOPICS))
    gw = gateways("--workers", "2", "--max-subscriptions", "100", "--log-level", "warning")
    paths = streams.open_streams(gw, APP, TOPICS, "normal", 600, STREAMS)
    rss_before = memory(gw.pid)
    measure_from = 3.0 + STREAMS / 400
    with HealthProbe(gw.port, interval=0.1) as probe:
        got = streams.read(gw, paths, measure_from + SECONDS, measure_from, clients=2, period=0.2,
                           connect_rate=200, grace=120)
        peak = max((b["x-medkit-streams"]["open_streams"] for b in probe.bodies()), default=0)
    poll_until(lambda: gw.get("/health").json()["x-medkit-streams"]["open_streams"] == 0, 15,
               message="every stream given back")
    rss_after = memory(gw.pid)
    ratio = streams.delivered_ratio(got)
    record("streams", probe=probe, restarts=restarts_in(gw.output), rss_before=rss_before,
           rss_after=rss_after, requests=got["opened"],
           statuses={"200 text/event-stream": got["opened"], "failed": got["failed"]},
           note=f"{STREAMS} streams on {len(TOPICS)} topics at normal for {SECONDS} s: "
                f"{ratio:.1%} of scheduled frames delivered, p99 lateness {got['lateness_p99_ms']:.0f} ms, "
                f"peak open_streams {peak}")
    streams.assert_held(gw, got, STREAMS, peak, probe)
    grew = (rss_after["http_sum"] or 0) - (rss_before["http_sum"] or 0)
    assert grew < 100, (rss_before, rss_after)      # MB, over both HTTP workers
