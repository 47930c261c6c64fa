"""Scenario 3, publisher churn: publishers appear, change type and disappear while clients read.

One long-lived helper process (``churn_node.py``) makes and drops publishers
on command, so a cycle costs milliseconds of process work.  Each topic of a
small set goes through cycles of

    String "c<n>" publisher appears  ->  it is replaced by an Int32 <n> publisher
    ->  the publisher disappears  ->  the gateway's subscription is gone

with a controller per topic waiting (through HTTP) for each step to be
visible, while reader clients read every topic all the time.  The pool cap
is below the number of topics, so LRU evictions churn too.

What must hold:

- every data answer is consistent: the type it names is the type of its data;
- reads never go back in time on a topic: once an answer showed version v
  (String c -> Int32 c -> gone -> String c+1 ...), no read started later
  shows an older one -- no stale type or value after the change was visible,
  and no data after "no publishers" was visible; a metadata answer never
  names the type that was replaced either;
- the gateway's own subscriber count on a dropped topic returns to 0, seen
  by the helper's independent view of the graph;
- the pool never exceeds its cap; no answer breaks the contract; no restart.
"""

from __future__ import annotations

import bisect
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time

from common.harness.procs import REPO, poll_until
from tests.reliability import load

TOPICS = [f"/churn/t{i}" for i in range(load.scaled(4, 6))]
CYCLES = load.scaled(40, 500)
READERS = load.scaled(6, 12)
POOL = len(TOPICS) - 1
STRING, INT32 = "std_msgs/msg/String", "std_msgs/msg/Int32"
STEP_TIMEOUT = 30.0  # hang catcher for one step of a cycle


class ChurnNode:
    """``python -m tests.reliability.churn_node``: JSON commands on stdin, one reply line each."""

    def __init__(self, name: str = "churn"):
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tests.reliability.churn_node", name], cwd=REPO,
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            start_new_session=True)
        self.output: list[str] = []
        self._replies: dict[int, dict] = {}
        self._ready = threading.Event()
        self._cond = threading.Condition()
        self._lock = threading.Lock()
        self._seq = 0
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        if not self._ready.wait(30):
            self.stop()
            raise AssertionError("churn node not ready:\n" + "\n".join(self.output[-20:]))

    def _read(self) -> None:
        for line in self.proc.stdout:
            line = line.rstrip("\n")
            self.output.append(line)
            if line == "READY":
                self._ready.set()
            elif line.startswith("{"):
                reply = json.loads(line)
                with self._cond:
                    self._replies[reply.get("seq")] = reply
                    self._cond.notify_all()

    def cmd(self, op: str, timeout: float = 10.0, **args) -> dict:
        with self._lock:
            self._seq += 1
            seq = self._seq
            self.proc.stdin.write(json.dumps({"seq": seq, "op": op, **args}) + "\n")
            self.proc.stdin.flush()
        with self._cond:
            if not self._cond.wait_for(lambda: seq in self._replies, timeout):
                raise AssertionError(f"churn node did not answer {op} within {timeout} s")
            reply = self._replies.pop(seq)
        assert reply["ok"], reply
        return reply

    def stop(self) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.stdin.close()
            except OSError:
                pass
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(5)


def sample_info(req, status, headers, body):
    """``(status, type, data value, reason)`` of a sample answer."""
    if status != 200:
        return None
    doc = json.loads(body)
    ext = doc["x-medkit"]
    return ext["status"], ext["ros2"].get("type"), doc["data"].get("data"), ext.get("reason")


def version(info) -> int | None:
    """String c -> 4c, Int32 c -> 4c+2 (gone answers get 4c+3 from the controller's marks)."""
    status, type_, value, _ = info
    if status != "data":
        return None
    if type_ == STRING:
        return 4 * int(value[1:])
    return 4 * value + 2


def inconsistent(info) -> bool:
    status, type_, value, _ = info
    if status != "data":
        return False
    if type_ == STRING:
        return not (isinstance(value, str) and value.startswith("c") and value[1:].isdigit())
    if type_ == INT32:
        return not (isinstance(value, int) and not isinstance(value, bool))
    return True


class Controller(threading.Thread):
    """Drives one topic through its cycles; records when each step was started (monotonic)."""

    def __init__(self, node: ChurnNode, port: int, path: str, topic: str, cycles: int, first: int):
        super().__init__(daemon=True, name=f"churn {topic}")
        self.node, self.port, self.path, self.topic = node, port, path, topic
        self.cycles = range(first, first + cycles)
        self.marks: dict[tuple[int, str], float] = {}   # (cycle, "A"|"B"|"gone") -> when it was made
        self.answers: list[load.Answer] = []
        self.error: BaseException | None = None
        self.drop_waits: list[float] = []
        self.subscribed_seen = 0   # cycles in which the helper saw the gateway's subscription

    def _until(self, predicate, what: str, client: load.Client) -> None:
        deadline = time.monotonic() + STEP_TIMEOUT
        while time.monotonic() < deadline:
            answer = load.call(client, load.Req("controller", "GET", self.path), sample_info)
            self.answers.append(answer)
            if answer.info is not None and predicate(answer.info):
                return
            time.sleep(0.02)
        raise AssertionError(f"{self.topic}: {what} not visible within {STEP_TIMEOUT} s")

    def run(self) -> None:
        client = load.Client(self.port)
        try:
            for c in self.cycles:
                self.marks[(c, "A")] = time.monotonic()
                self.node.cmd("pub", id=self.topic, topic=self.topic, type=STRING, rate=20,
                              value={"data": f"c{c}"})
                self._until(lambda i, c=c: i[0] == "data" and i[1:3] == (STRING, f"c{c}"), f"String c{c}",
                            client)
                self.marks[(c, "B")] = time.monotonic()
                self.node.cmd("pub", id=self.topic, topic=self.topic, type=INT32, rate=20, value={"data": c})
                self._until(lambda i, c=c: i[0] == "data" and i[1:3] == (INT32, c), f"Int32 {c}", client)
                self.subscribed_seen += self.node.cmd("count", topic=self.topic)["subscribers"] >= 1
                self.marks[(c, "gone")] = time.monotonic()
                self.node.cmd("unpub", id=self.topic)
                self._until(lambda i: i[3] in ("no-publishers", "not-in-graph"), "no publishers", client)
                started = time.monotonic()
                poll_until(lambda: self.node.cmd("count", topic=self.topic)["subscribers"] == 0,
                           STEP_TIMEOUT, interval=0.02,
                           message=f"the gateway's subscription on {self.topic} dropped (cycle {c})")
                self.drop_waits.append(time.monotonic() - started)
        except BaseException as exc:
            self.error = exc
        finally:
            client.close()


STEPS = ("A", "B", "gone")


def state_at(marks: dict[tuple[int, str], float], when: float) -> int | None:
    """The version a "no publishers" answer started at ``when`` stands for.

    After ``gone`` of cycle c: 4c+3.  After ``B`` of cycle c (the String
    publisher was dropped, the Int32 one not seen yet): 4c+1.  After ``A`` of
    cycle c (not seen yet): the gone state of cycle c-1, or None before the first.
    """
    latest = max(((t, c, s) for (c, s), t in marks.items() if t <= when), default=None)
    if latest is None:
        return None
    _, c, step = latest
    if step == "gone":
        return 4 * c + 3
    if step == "B":
        return 4 * c + 1
    return 4 * (c - 1) + 3 if (c - 1, "gone") in marks else None


def stale_label(label: str, seen: int, finished: float, marks: dict[tuple[int, str], float]) -> bool:
    """A metadata answer names ``label`` though that publisher was seen replaced or gone."""
    c, step = divmod(seen, 4)
    if label == INT32 and step in (0, 3):   # Int32 of cycle c-1 (or c) was gone for good
        return finished < marks.get((c + (step == 3), "B"), math.inf)
    if label == STRING and step in (1, 2, 3):  # String of cycle c was replaced
        return finished < marks.get((c + 1, "A"), math.inf)
    return False


def check_topic(topic: str, answers: list[load.Answer], marks: dict[tuple[int, str], float]) -> list[str]:
    """The consistency rules of the module docstring, for one topic's answers.

    A data answer has an exact version.  A "no publishers" answer was decided
    at some moment between its start and its end, so it stands for any state
    from ``state_at(started)`` to ``state_at(finished)``.  An answer goes back
    in time when an answer that finished before it started had a higher
    (lowest possible) version than its highest possible one.
    """
    faults = []
    versioned = []  # (started, finished, lowest version, highest version, answer)
    for a in answers:
        if a.info is None:
            continue
        if inconsistent(a.info):
            faults.append(f"inconsistent answer {a.info}")
            continue
        v = version(a.info)
        if v is not None:
            versioned.append((a.started, a.finished, v, v, a))
        elif a.info[3] in ("no-publishers", "not-in-graph"):
            low, high = state_at(marks, a.started), state_at(marks, a.finished)
            if high is not None:
                versioned.append((a.started, a.finished, -1 if low is None else low, high, a))
    by_finish = sorted(versioned, key=lambda x: x[1])
    finishes = [x[1] for x in by_finish]
    prefix_max, best = [], (-1, None)
    for x in by_finish:
        if x[2] > best[0]:
            best = (x[2], x[4])
        prefix_max.append(best)
    for started, _, _, high, a in versioned:
        i = bisect.bisect_left(finishes, started) - 1
        if i >= 0 and prefix_max[i][0] > high:
            seen, earlier = prefix_max[i]
            faults.append(f"went back in time: version ≤{high} ({a.info}) after version {seen} "
                          f"({earlier.info}) was visible")
    for a in answers:
        if a.info is None or a.info[0] != "metadata_only" or a.info[1] is None:
            continue
        i = bisect.bisect_left(finishes, a.started) - 1
        if i >= 0 and stale_label(a.info[1], prefix_max[i][0], a.finished, marks):
            faults.append(f"metadata answer names {a.info[1]} after version {prefix_max[i][0]} "
                          f"({prefix_max[i][1].info}) was visible")
    return faults


def test_publisher_churn_never_serves_stale_types_and_drops_subscriptions(gateways):
    node = ChurnNode()
    try:
        gw = gateways("--max-pool-size", str(POOL), "--log-level", "warning")
        host = gw.get("/components").json()["items"][0]["id"]
        base = f"/api/v1/components/{host}/data"
        rss_before = load.memory(gw.pid)
        per_topic = math.ceil(CYCLES / len(TOPICS))
        controllers = [Controller(node, gw.port, base + t, t, per_topic, 1) for t in TOPICS]
        readers = load.Load(gw.port, lambda rng: load.Req("reader", "GET", base + rng.choice(TOPICS)), READERS,
                       inspect=sample_info)
        started = time.monotonic()
        with load.HealthProbe(gw.port, interval=0.05) as probe:
            readers.start()
            for c in controllers:
                c.start()
            for c in controllers:
                c.join(per_topic * 4 * STEP_TIMEOUT)
            readers.stop()
            read = readers.join(60)
        took = time.monotonic() - started
        hung = [c.topic for c in controllers if c.is_alive()]
        assert not hung, f"controllers hung: {hung}"
        rss_after = load.memory(gw.pid)
        everything = read + [a for c in controllers for a in c.answers]
        waits = sorted(w for c in controllers for w in c.drop_waits)
        load.record("publisher churn", everything, probe=probe, restarts=load.restarts_in(gw.output),
               rss_before=rss_before, rss_after=rss_after,
               note=f"{per_topic * len(TOPICS)} cycles on {len(TOPICS)} topics in {took:.0f} s, "
                    f"pool cap {POOL}, subscription gone after ≤{waits[-1] * 1000:.0f} ms"
                    if waits else "")
        for c in controllers:
            if c.error is not None:
                raise c.error

        problems = [a for a in everything if a.problem or isinstance(a.status, str)]
        assert not problems, [(a.path, a.status, a.problem) for a in problems[:5]]
        faults = []
        for topic in TOPICS:
            ctl = next(c for c in controllers if c.topic == topic)
            mine = [a for a in everything if a.path.endswith(topic)]
            faults += [f"{topic}: {f}" for f in check_topic(topic, mine, ctl.marks)]
        assert not faults, f"{len(faults)} stale answers, e.g. {faults[:5]}"
        # The independent observer does see the gateway's subscriptions (so "0" above means gone).
        assert sum(c.subscribed_seen for c in controllers) > 0
        assert probe.samples and all(s[2] == 200 for s in probe.samples)
        assert probe.max_of("x-medkit-data-provider", "pool_size") <= POOL
        assert load.restarts_in(gw.output) == 0
        # After the churn: every topic is gone, and with it every subscription of the gateway.
        for topic in TOPICS:
            counts = node.cmd("count", topic=topic)
            assert (counts["publishers"], counts["subscribers"]) == (0, 0), (topic, counts)
        poll_until(lambda: gw.get("/health").json()["x-medkit-data-provider"]["pool_size"] == 0, 15,
                   message="pool empty once every publisher is gone")
    finally:
        node.stop()


def test_check_topic_catches_stale_answers():
    """The checker itself: a read that goes back in time, or names a replaced type, is caught."""
    def ans(started, finished, info):
        return load.Answer("r", "/churn/x", started, finished - started, 200, "200", None, info)

    marks = {(1, "A"): 0.0, (1, "B"): 1.0, (1, "gone"): 2.0, (2, "A"): 3.0}
    good = [ans(0.1, 0.2, ("data", STRING, "c1", None)), ans(1.1, 1.2, ("data", INT32, 1, None)),
            ans(2.1, 2.2, ("metadata_only", None, {}, "no-publishers")),
            ans(3.1, 3.2, ("data", STRING, "c2", None))]
    assert check_topic("/churn/x", good, marks) == []
    back = good + [ans(1.3, 1.4, ("data", STRING, "c1", None))]
    assert "went back in time" in check_topic("/churn/x", back, marks)[0]
    after_gone = good[:3] + [ans(2.3, 2.4, ("data", INT32, 1, None))]
    assert "went back in time" in check_topic("/churn/x", after_gone, marks)[0]
    label = good[:2] + [ans(1.3, 1.4, ("metadata_only", STRING, {}, "timeout"))]
    assert "names std_msgs/msg/String" in check_topic("/churn/x", label, marks)[0]
    # The String publisher is dropped before the Int32 one is seen: "no publishers" is fine,
    # String data after it is not.
    gap = good[:1] + [ans(1.1, 1.2, ("metadata_only", None, {}, "no-publishers")),
                      ans(1.3, 1.4, ("data", INT32, 1, None))]
    assert check_topic("/churn/x", gap, marks) == []
    assert "went back in time" in check_topic(
        "/churn/x", gap + [ans(1.25, 1.3, ("data", STRING, "c1", None))], marks)[0]
    # A read started before the drop and answered after it: fine.
    across = good[:2] + [ans(1.9, 2.1, ("metadata_only", None, {}, "no-publishers"))]
    assert check_topic("/churn/x", across, marks) == []
    mixed = [ans(0.1, 0.2, ("data", STRING, 5, None))]
    assert "inconsistent" in check_topic("/churn/x", mixed, marks)[0]
    # Overlapping reads may finish in any order: no fault.
    overlap = [ans(1.0, 1.5, ("data", STRING, "c1", None)), ans(1.1, 1.2, ("data", INT32, 1, None))]
    assert check_topic("/churn/x", overlap, marks) == []
