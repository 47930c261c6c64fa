"""``make bench``: the gateway side by side with its floor and with the old design, in one run.

    python -m bench.run [--quick] [--out DIR] [--no-install] [--python-load] [--profile]

Starts, in a private ROS domain with localhost-only discovery: the demo
robot (``demo/robot.py``), a real ``sovd-gateway`` (console script, default
settings, log level ``warning`` so that gunicorn writes no access log line
per request, ``--debug-commands`` for the echo route), the echo process
(``bench/echoworker.py``), and per case its own publishers
(``bench/benchpub.py``).  Then
it measures every case below, prints the table and writes it as JSON to
``bench/results/bench-<UTC timestamp>.json``.  Every target is a ratio or a
difference between figures of the same run.

| case | how |
|---|---|
| floor | ``GET /api/v1/version-info`` (touches no ROS worker), 8 and 1 connections |
| warm sample | ``GET .../data/powertrain/engine/temperature`` (10 Hz, pooled), 8 and 1 connections |
| echo route | ``GET /api/v1/x-sovd-debug/echo``: one round trip through the same HTTP stack and IPC client to a process that answers at once (``bench/echoworker.py``), 8 and 1 connections: the pure hop |
| IPC hop | ``GET /api/v1/health`` (one ``stats`` round trip, no ROS work), 1 connection: report only |
| old design | ``bench/oldsampler.py``: create a subscription, wait for a message, destroy it |
| cold sample | the first HTTP read of a fresh 10 Hz topic, one topic per read |
| image | 640×480 rgb8 at 10 Hz, 1 connection, integer arrays, then ``?bytes=base64`` |
| idle cost | ROS worker CPU, 50 pooled topics at 100 Hz, no readers, next to ``bench/ddsfloor.py`` |
| memory | ROS worker RSS before and with 256 pooled topics |
| streams | 1,000 SSE streams on 10 topics at ``normal`` for 30 s (``bench/streams.py``), then 10 on the same topics |
| stream image | a 640×480 rgb8 image at 5 Hz streamed at ``fast`` (``?bytes=base64``): publish stamp to client |
| made-up topics | ROS worker CPU with 1,000 ``fast`` subscriptions on topics nobody publishes, against the same worker holding none |
| subscription changes | median POST and DELETE of a cyclic subscription with 100 and with 900 held, beside ``/version-info`` |
| service call | ``POST …/operations/calibrate/executions`` (the demo's ``std_srvs/Trigger``), 1 connection, against a bare rclpy client (``bench/operations.py``) |
| auth | ``bench/auth.py``: the warm sample through a gateway with ``--auth-enabled --require-auth-for all`` (a JWT on every request) against the same read without authentication, alternating rounds |
| write checks | ``bench/auth.py``: ``PUT`` of the demo's lights command with the lock check (a lock held on another app) and the audit record, against a gateway with neither |
| bulk data | ``bench/bulk_data.py``: ROS worker CPU recording 10 topics at 100 Hz against the same topics pooled; warm sample p50 while recordings are written against without; a 200 MB recording downloaded from the gateway against nginx serving the same file |
| fleet | ``bench/fleet.py``: ``GET /faults`` on the fleet gateway over 500 simulated robots (``bench/fleetsim.py``) against a robot's own, one of them hung; a fault to the fleet's stream; the fleet gateway's memory; a robot's idle CPU with the fleet link on against off |

Floor, warm sample and echo route are measured in alternating rounds (floor
-c8, sample -c8, echo -c8, floor -c1, sample -c1, echo -c1, health -c1, six
times); each target is the median over the rounds of the paired ratio or
difference, so that a slow moment of the machine does not land on one side only.  The gateway's CPU per request is
recorded beside (load-independent).

Exit status: 0 every target met, 2 some target missed, 1 the run itself
failed (what was measured is still written).

``--quick`` runs every case briefly (seconds instead of minutes) for the
smoke test; its figures are not meant to be read and it exits 0 whatever
they are.  ``--profile`` also runs py-spy against the ROS worker and one
HTTP worker under 8-connection load and stores the collapsed stacks beside
the JSON.
"""

from __future__ import annotations

import argparse
import datetime as dt
import http.client
import json
import os
import platform
import random
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import psutil
import requests

from app.core.debug import echo_endpoint
from common.harness.gateway import Gateway
from common.harness.procs import Proc, poll_until, private_ros_domain
from ipc.client import RosWorkerClient

from . import load as loadgen
from . import operations, streams
from .procs import cpu_seconds, measure_cpu, robot, ros_helper

RESULTS = Path(__file__).resolve().parent / "results"
WARM_TOPIC = "/powertrain/engine/temperature"   # demo robot, sensor_msgs/msg/Temperature, 10 Hz
WARM_APP = "temp_sensor"
IMAGE_TOPIC = "/bench/camera/image"

FULL = {"rounds": 6, "load_s": 2.5, "warmup_s": 2.0, "image_s": 8.0, "old_n": 30, "cold_n": 20,
        "idle_topics": 50, "idle_rate": 100, "idle_s": 10.0, "mem_topics": 256,
        "streams": 1000, "streams_s": 30.0, "stream_image_s": 20.0,
        "made_up": 1000, "made_up_s": 10.0, "sub_sizes": (100, 900), "sub_rounds": 50}
QUICK = {"rounds": 1, "load_s": 1.0, "warmup_s": 0.0, "image_s": 1.0, "old_n": 3, "cold_n": 3,
         "idle_topics": 50, "idle_rate": 100, "idle_s": 2.0, "mem_topics": 16,
         "streams": 40, "streams_s": 3.0, "stream_image_s": 3.0,
         "made_up": 20, "made_up_s": 1.0, "sub_sizes": (5, 25), "sub_rounds": 3}

TARGETS = {
    "warm_rps_ratio": 0.7,        # warm sample 8 conn ≥ 0.7 × floor
    "warm_p50_extra_ms": 0.3,     # warm sample 1 conn p50 ≤ floor p50 + 0.3 ms
    "warm_echo_rps_ratio": 0.85,  # warm sample 8 conn ≥ 0.85 × echo route
    "warm_echo_p50_extra_ms": 0.15,  # warm sample 1 conn p50 ≤ echo route p50 + 0.15 ms
    "old_speedup": 100.0,         # old design p50 ≥ 100 × warm p50
    "cold_p50_ms": 150.0,
    "image_p50_ms": 30.0,
    "idle_cpu_ratio": 1.5,
}


def log(text: str) -> None:
    print(f"[bench {time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------- helpers

class Bench:
    def __init__(self, args: argparse.Namespace):
        self.args = args
        self.p = dict(QUICK if args.quick else FULL)
        if args.rounds:
            self.p["rounds"] = args.rounds
        self.rows: list[dict[str, Any]] = []
        self.procs: list[Proc] = []
        self.gw: Gateway | None = None
        self.ipc: RosWorkerClient | None = None
        self.load: loadgen.Load | None = None
        self.work_dir = tempfile.mkdtemp(prefix="sovd-bench-logs-")
        self.host_id = ""
        self.extra: dict[str, Any] = {}

    # ---- infrastructure ----
    def start(self) -> None:
        domain = private_ros_domain()
        log(f"ROS_DOMAIN_ID={domain}, localhost-only discovery; logs in {self.work_dir}")
        if self.args.python_load:
            wrk, note = None, "Python fallback forced (--python-load)"
        else:
            wrk, note = loadgen.ensure_wrk(install=not self.args.no_install)
        self.load = loadgen.Load(wrk, note)
        log(f"load generator: {self.load.name} {note}")
        self.procs.append(ros_helper_demo())
        self.gw = Gateway("--log-level", "warning", "--debug-commands", "--allow-operations",
                          *self.args.gateway_args.split(),
                          log_path=os.path.join(self.work_dir, "gateway.log"))
        echo = Proc([sys.executable, "-m", "bench.echoworker", echo_endpoint(self.gw.runtime_dir)],
                    name="echo worker")
        self.procs.append(echo)
        echo.wait_line(lambda line: line == "READY", 30)
        self.ipc = RosWorkerClient.for_runtime_dir(self.gw.runtime_dir)
        comps = requests.get(self.gw.api + "/components", timeout=5).json()["items"]
        self.host_id = comps[0]["id"]
        log(f"gateway on {self.gw.url} (ROS worker pid {self.gw.rosworker().pid}, "
            f"HTTP workers {[p.pid for p in self.gw.http_workers()]})")

    def stop(self) -> None:
        for proc in reversed(self.procs):
            try:
                proc.stop(timeout=5)
            except Exception as exc:  # noqa: BLE001 - keep stopping the others
                log(f"stopping {proc.name}: {exc!r}")
        if self.ipc is not None:
            self.ipc.close()
        if self.gw is not None:
            self.gw.stop()

    def call(self, cmd: str, args: dict | None = None, timeout: float = 5.0) -> dict:
        return self.ipc.call(cmd, args, timeout)

    def url(self, topic: str, entity: str | None = None, query: str = "") -> str:
        entity = entity or f"components/{self.host_id}"
        return f"{self.gw.api}/{entity}/data{topic}" + (f"?{query}" if query else "")

    def wait_data(self, url: str, timeout: float = 30.0, streak: int = 8) -> dict:
        """Poll until ``streak`` answers in a row (0.1 s apart) have data.

        Each HTTP worker refreshes its view of the ROS graph on its own (every 0.2 s), so one
        good answer right after start-up does not mean that the other worker knows the
        entity yet; a streak of answers spread over most of a second covers them all.
        """
        state = {"n": 0, "body": None}

        def ok():
            r = requests.get(url, timeout=10)
            body = r.json()
            good = r.status_code == 200 and body["x-medkit"]["status"] == "data"
            state["n"] = state["n"] + 1 if good else 0
            state["body"] = body
            return state["n"] >= streak
        poll_until(ok, timeout, interval=0.1, message=f"data at {url}")
        return state["body"]

    def wait_topics(self, topics: list[str], timeout: float = 60.0) -> None:
        wanted = set(topics)

        def seen():
            graph = self.call("graph")
            have = {t["name"] for t in graph.get("topics", []) if t.get("publisher_count")}
            return wanted <= have
        poll_until(seen, timeout, interval=0.2, message=f"{len(wanted)} topics in the ROS worker's graph")

    def pool_topics(self, topics: list[str], timeout: float = 60.0) -> None:
        pending = list(topics)

        def pooled():
            nonlocal pending
            pending = [t for t in pending if self.call("subscribe", {"topic": t})["status"] != "pooled"]
            return not pending
        poll_until(pooled, timeout, interval=0.2, message=f"{len(topics)} topics pooled")

    def evict_all(self) -> None:
        for topic in self.call("pool")["topics"]:
            self.call("evict", {"topic": topic})

    def stop_proc(self, proc: Proc) -> None:
        proc.stop(timeout=5)
        if proc in self.procs:
            self.procs.remove(proc)

    def add(self, key: str, case: str, how: str, values: dict[str, Any], measured: str,
            target: str = "—", passed: bool | None = None) -> None:
        row = {"key": key, "case": case, "how": how, "values": values, "measured": measured,
               "target": target, "result": "report" if passed is None else ("PASS" if passed else "FAIL")}
        self.rows.append(row)
        log(f"{case}: {measured}  [{row['result']}]")

    # ---- cases ----
    def run_cases(self) -> None:
        # memory before image/cold/idle: its "before" RSS is not their high-water mark
        cases = {"warm": self.case_floor_and_warm, "old": self.case_old_design,
                 "memory": self.case_memory, "image": self.case_image, "cold": self.case_cold,
                 "idle": self.case_idle, "streams": self.case_streams, "stream_image": self.case_stream_image,
                 "sub_costs": self.case_sub_costs,
                 "operations": lambda: operations.case_trigger(self)}  # operations: a Trigger call
        # configurations: GET and PUT of a parameter vs a bare rclpy parameter client (bench/params.py)
        cases["params"] = lambda: __import__("bench.params", fromlist=["case"]).case(self)
        # logs (issue 22): /rosout at 1 kHz vs its DDS floor (bench/logs.py)
        from . import logs as rosout_logs
        cases["rosout"] = lambda: rosout_logs.case_rosout(self)
        # faults (issue 22): /diagnostics at 10 Hz × 50 statuses vs its DDS floor, and the confirm latency
        from . import faults as fault_bench
        cases["faults"] = lambda: fault_bench.case(self)
        # fleet (issue 34): the fleet gateway over 500 simulated robots; a robot's cost of the link
        from . import fleet as fleet_bench
        cases["fleet"] = lambda: fleet_bench.case(self)
        # who is acting (issue 31): a JWT checked on every warm sample; a write's lock check and audit record
        from . import auth as auth_bench
        cases["auth"] = lambda: auth_bench.case_auth(self)
        cases["write_checks"] = lambda: auth_bench.case_write(self)
        # bulk data (issue 32): recording's CPU, warm samples during a write, a 200 MB download vs nginx
        from . import bulk_data as bulk_bench
        cases["bulk_data"] = lambda: bulk_bench.case(self)
        # the ROS worker wakes only on events (issue 33): idle with a trigger and a goal open; trigger fan-out
        from . import wakeups
        cases["wake_idle"] = lambda: wakeups.case_idle(self)
        cases["triggers"] = lambda: wakeups.case_triggers(self)
        only = set(self.args.only.split(",")) if self.args.only else set(cases)
        if "old" in only:
            only.add("warm")  # the old design is compared with the warm sample
        for name, case in cases.items():
            if name in only:
                case()

    def _load(self, url: str, connections: int, seconds: float) -> loadgen.LoadResult:
        return self.load.run(url, connections, seconds)

    def _gateway_cpu(self) -> float:
        """CPU seconds used so far by the ROS worker and the HTTP workers."""
        total = 0.0
        for proc in [self.gw.rosworker(), *self.gw.http_workers()]:
            try:
                total += cpu_seconds(proc)
            except psutil.NoSuchProcess:
                pass
        return total

    def _paired_load(self, url: str, connections: int, seconds: float) -> loadgen.LoadResult:
        before = self._gateway_cpu()
        result = self._load(url, connections, seconds)
        used = self._gateway_cpu() - before
        result["gateway_cpu_us_per_request"] = round(used / result["requests"] * 1e6) if result["requests"] else 0
        return result

    def case_floor_and_warm(self) -> None:
        """Floor, warm sample and echo route in alternating rounds; targets on the median of paired rounds.

        Each round measures floor -c8, warm -c8, echo -c8, floor -c1, warm -c1, echo -c1 and
        health -c1 back to back, so each
        ratio (throughput) and difference (p50) compares figures taken seconds apart; the
        verdict uses the median over the rounds of these paired figures, which drift in the
        machine's load does not decide.  The gateway's own CPU per request (ROS worker and
        HTTP workers, psutil) is recorded beside, as the load-independent view of cost.
        """
        p = self.p
        floor_url = self.gw.api + "/version-info"
        warm_url = self.url(WARM_TOPIC, f"apps/{WARM_APP}")
        echo_url = self.gw.api + "/x-sovd-debug/echo"
        self.wait_data(warm_url)
        poll_until(lambda: requests.get(echo_url, timeout=5).status_code == 200, 10, message="the echo route")
        if p["warmup_s"]:
            for url in (floor_url, warm_url, echo_url):
                self._load(url, 8, p["warmup_s"])
        health_url = self.gw.api + "/health"
        order = (("floor8", floor_url, 8), ("warm8", warm_url, 8), ("echo8", echo_url, 8),
                 ("floor1", floor_url, 1), ("warm1", warm_url, 1), ("echo1", echo_url, 1),
                 ("hop1", health_url, 1))
        runs: dict[str, list[loadgen.LoadResult]] = {key: [] for key, _, _ in order}
        inside_before = self.call("stats")["details"]["commands"].get("sample", {"count": 0, "time_us": 0})
        ratios, extras, hops, echo_ratios, echo_extras, echo_hops = [], [], [], [], [], []
        for i in range(p["rounds"]):
            for key, url, conns in order:
                runs[key].append(self._paired_load(url, conns, p["load_s"]))
            f8, w8, e8, f1, w1, e1, h1 = (runs[k][-1] for k, _, _ in order)
            ratios.append(w8["rps"] / f8["rps"] if f8["rps"] else 0.0)
            extras.append(w1["p50_ms"] - f1["p50_ms"])
            hops.append(h1["p50_ms"] - f1["p50_ms"])
            echo_ratios.append(w8["rps"] / e8["rps"] if e8["rps"] else 0.0)
            echo_extras.append(w1["p50_ms"] - e1["p50_ms"])
            echo_hops.append(e1["p50_ms"] - f1["p50_ms"])
            log(f"round {i + 1}/{p['rounds']}: -c8 floor {f8['rps']:.0f} warm {w8['rps']:.0f} echo {e8['rps']:.0f} "
                f"req/s (warm = {ratios[-1]:.2f} x floor, {echo_ratios[-1]:.2f} x echo); -c1 p50 floor "
                f"{f1['p50_ms']:.3f} warm {w1['p50_ms']:.3f} echo {e1['p50_ms']:.3f} ms (warm = floor "
                f"+{extras[-1]:.3f}, echo {echo_extras[-1]:+.3f}) health {h1['p50_ms']:.3f} ms (+{hops[-1]:.3f}); "
                f"gateway CPU/request floor {f8['gateway_cpu_us_per_request']} warm "
                f"{w8['gateway_cpu_us_per_request']} echo {e8['gateway_cpu_us_per_request']} us")
        if self.args.profile:
            self.profile(warm_url)

        def med(key: str) -> dict[str, Any]:
            v = runs[key]
            return {"rps": statistics.median(r["rps"] for r in v),
                    "p50_ms": statistics.median(r["p50_ms"] for r in v),
                    "p99_ms": statistics.median(r["p99_ms"] for r in v),
                    "gateway_cpu_us_per_request": statistics.median(r["gateway_cpu_us_per_request"] for r in v),
                    "errors": sum(r["errors"] for r in v), "rounds": v}

        m = {k: med(k) for k in runs}
        ratio, extra = statistics.median(ratios), statistics.median(extras)
        n = p["rounds"]
        gen = self.load.name.split(" ")[0]
        self.add("floor8", "floor, 8 connections", f"{gen} -c8 GET /api/v1/version-info, {n} rounds",
                 m["floor8"], f"{m['floor8']['rps']:.0f} req/s, p50 {m['floor8']['p50_ms']:.3f} ms, "
                 f"gateway CPU {m['floor8']['gateway_cpu_us_per_request']:.0f} us/req")
        self.add("floor1", "floor, 1 connection", f"{gen} -c1 GET /api/v1/version-info, {n} rounds",
                 m["floor1"], f"p50 {m['floor1']['p50_ms']:.3f} ms, {m['floor1']['rps']:.0f} req/s")
        self.add("warm8", "warm sample, small message, 8 connections",
                 f"{gen} -c8 GET .../data{WARM_TOPIC} (Temperature, 10 Hz), paired with the floor",
                 {**m["warm8"], "ratio_to_floor": round(ratio, 3), "paired_ratios": [round(x, 3) for x in ratios]},
                 f"{m['warm8']['rps']:.0f} req/s; paired median {ratio:.2f} × floor; gateway CPU "
                 f"{m['warm8']['gateway_cpu_us_per_request']:.0f} us/req"
                 + (f"; {m['warm8']['errors']} errors" if m["warm8"]["errors"] else ""),
                 f"≥ {TARGETS['warm_rps_ratio']} × floor",
                 ratio >= TARGETS["warm_rps_ratio"] and m["warm8"]["errors"] == 0)
        self.add("warm1", "warm sample, 1 connection", f"{gen} -c1 GET .../data{WARM_TOPIC}, paired with the floor",
                 {**m["warm1"], "extra_over_floor_ms": round(extra, 3),
                  "paired_extras_ms": [round(x, 3) for x in extras]},
                 f"p50 {m['warm1']['p50_ms']:.3f} ms; paired median floor + {extra:.3f} ms",
                 f"≤ floor p50 + {TARGETS['warm_p50_extra_ms']} ms",
                 extra <= TARGETS["warm_p50_extra_ms"] and m["warm1"]["errors"] == 0)
        echo_ratio, echo_extra = statistics.median(echo_ratios), statistics.median(echo_extras)
        echo_hop = statistics.median(echo_hops)
        self.add("echo8", "echo route (the pure hop), 8 connections",
                 f"{gen} -c8 GET /api/v1/x-sovd-debug/echo: one round trip through the same HTTP stack and "
                 "IPC client to a process that answers at once; paired with the warm sample",
                 {**m["echo8"], "warm_ratio_to_echo": round(echo_ratio, 3),
                  "paired_warm_ratios": [round(x, 3) for x in echo_ratios]},
                 f"{m['echo8']['rps']:.0f} req/s, gateway CPU {m['echo8']['gateway_cpu_us_per_request']:.0f} "
                 f"us/req; warm sample = {echo_ratio:.2f} × echo (paired median)",
                 f"warm ≥ {TARGETS['warm_echo_rps_ratio']} × echo",
                 echo_ratio >= TARGETS["warm_echo_rps_ratio"] and m["echo8"]["errors"] == 0
                 and m["warm8"]["errors"] == 0)
        self.add("echo1", "echo route (the pure hop), 1 connection",
                 f"{gen} -c1 GET /api/v1/x-sovd-debug/echo, paired with the warm sample and the floor",
                 {**m["echo1"], "warm_extra_over_echo_ms": round(echo_extra, 3),
                  "paired_warm_extras_ms": [round(x, 3) for x in echo_extras],
                  "extra_over_floor_ms": round(echo_hop, 3)},
                 f"p50 {m['echo1']['p50_ms']:.3f} ms = floor + {echo_hop:.3f} ms; warm sample = echo "
                 f"{echo_extra:+.3f} ms (paired medians)",
                 f"warm p50 ≤ echo p50 + {TARGETS['warm_echo_p50_extra_ms']} ms",
                 echo_extra <= TARGETS["warm_echo_p50_extra_ms"] and m["echo1"]["errors"] == 0
                 and m["warm1"]["errors"] == 0)
        inside = self.call("stats")["details"]["commands"]["sample"]
        n_inside = inside["count"] - inside_before["count"]
        us_inside = (inside["time_us"] - inside_before["time_us"]) / n_inside if n_inside else 0.0
        self.add("inside", "warm sample inside the ROS worker",
                 "the worker's own time per queued sample command on its ROS thread (take + cached JSON "
                 "+ reply), over every warm sample of the rounds",
                 {"us_per_sample": round(us_inside, 1), "samples": n_inside},
                 f"{us_inside:.0f} us per sample over {n_inside} samples")
        hop = statistics.median(hops)
        self.add("hop1", "IPC hop alone (/health), 1 connection",
                 f"{gen} -c1 GET /api/v1/health: one round trip to the ROS worker, answered by whichever "
                 "thread holds its socket, no ROS work; paired with the floor",
                 {**m["hop1"], "extra_over_floor_ms": round(hop, 3), "paired_extras_ms": [round(x, 3) for x in hops],
                  "warm_minus_hop_ms": round(extra - hop, 3)},
                 f"p50 {m['hop1']['p50_ms']:.3f} ms; paired median floor + {hop:.3f} ms; the warm sample "
                 f"costs {extra - hop:+.3f} ms beyond this hop")
        errors = sum(x["errors"] for x in m.values())
        if errors:
            log(f"WARNING: {errors} HTTP errors during floor/warm runs: "
                + str([r.get("error_kinds") for v in runs.values() for r in v if r["errors"]]))

    def case_old_design(self) -> None:
        n = self.p["old_n"]
        proc = ros_helper("oldsampler", WARM_TOPIC, str(n), "2.0", name="oldsampler")
        line = proc.wait_line(lambda x: x.startswith("{"), 30 + n * 2.5)
        self.stop_proc_quiet(proc)
        raw = json.loads(line)
        samples = raw.get("samples_ms", [])
        p50 = statistics.median(samples) if samples else float("inf")
        warm = next(r for r in self.rows if r["key"] == "warm1")["values"]["p50_ms"]
        speedup = p50 / warm if warm else 0.0
        self.add("old", "old design (subscribe per request)",
                 f"bench/oldsampler.py, rclpy: create sub, wait 1st msg, destroy; {n}× on {WARM_TOPIC}",
                 {"p50_ms": round(p50, 3), "min_ms": min(samples, default=None),
                  "max_ms": max(samples, default=None), "timeouts": raw.get("timeouts"), "samples_ms": samples,
                  "speedup_of_warm_1conn": round(speedup, 1)},
                 f"p50 {p50:.1f} ms; warm pooled sample is {speedup:.0f}× faster",
                 f"warm ≥ {TARGETS['old_speedup']:.0f}× faster", speedup >= TARGETS["old_speedup"])

    def stop_proc_quiet(self, proc: Proc) -> None:
        try:
            proc.stop(timeout=5)
        except Exception as exc:  # noqa: BLE001
            log(f"stopping {proc.name}: {exc!r}")

    def case_image(self) -> None:
        cam = robot("bench_camera", [{"topic": IMAGE_TOPIC, "rate": 10, "kind": "image"}])
        self.procs.append(cam)
        array_url = self.url(IMAGE_TOPIC)
        b64_url = self.url(IMAGE_TOPIC, query="bytes=base64")
        self.wait_data(array_url)
        self.wait_data(b64_url)
        res = {}
        for key, url in (("array", array_url), ("base64", b64_url)):
            if self.p["warmup_s"]:
                self._load(url, 1, 1)
            res[key] = self._load(url, 1, self.p["image_s"])
        gen = self.load.name.split(" ")[0]
        a, b = res["array"], res["base64"]
        self.add("image", "640×480 rgb8 image, warm, 1 connection",
                 f"{gen} -c1, JSON with integer arrays (the contract), image at 10 Hz",
                 dict(a), f"p50 {a['p50_ms']:.2f} ms, p99 {a['p99_ms']:.2f} ms, "
                 f"{a['bytes_per_request'] / 1e6:.2f} MB/answer", f"p50 ≤ {TARGETS['image_p50_ms']:.0f} ms",
                 a["p50_ms"] <= TARGETS["image_p50_ms"] and a["errors"] == 0)
        self.add("image_b64", "same image with ?bytes=base64", f"{gen} -c1, uint8[] as one base64 string",
                 dict(b), f"p50 {b['p50_ms']:.2f} ms, p99 {b['p99_ms']:.2f} ms, "
                 f"{b['bytes_per_request'] / 1e6:.2f} MB/answer")
        self.stop_proc(cam)
        self.evict_all()

    def case_streams(self) -> None:
        n, seconds = self.p["streams"], self.p["streams_s"]
        got = streams.case_streams(self.gw, n, seconds)
        self.extra["streams"] = got
        many, few, t = got["many"], got["few"], streams.TARGETS
        ratio = many["delivered_ratio"]
        passed = (ratio >= t["streams_delivered"] and many["lateness_p99_ms"] <= t["streams_lateness_p99_ms"]
                  and many["health_p99_ms"] <= t["streams_health_p99_ms"]
                  and many["warm_p99_ms"] <= t["streams_warm_p99_ms"] and many["failed"] == 0
                  # issue 23: lateness p50 and the HTTP side's CPU per delivered frame
                  and many["lateness_p50_ms"] <= t["streams_lateness_p50_ms"]
                  and got["http_cpu_us_per_frame"] <= t["streams_http_us_per_frame"])
        self.add("streams", f"{n} SSE streams, 10 topics at normal",
                 f"{n // 10} streams per topic, {many['delivered'] / seconds:,.0f} frames/s for {seconds:g} s, "
                 "2 reader processes; /health, a warm GET and /version-info every 0.1 s meanwhile",
                 many, f"{ratio:.2%} of scheduled frames delivered (min {many['per_stream_min']} per stream), "
                 f"lateness p50 {many['lateness_p50_ms']:.0f} / p99 {many['lateness_p99_ms']:.0f} ms, "
                 f"/health p99 {many['health_p99_ms']:.1f} ms, warm GET p99 {many['warm_p99_ms']:.1f} ms "
                 f"(reference, no IPC: /version-info p99 {many['floor_p99_ms']:.1f} ms; with 10 streams: "
                 f"/health {few['health_p99_ms']:.1f}, warm {few['warm_p99_ms']:.1f}, /version-info "
                 f"{few['floor_p99_ms']:.1f} ms); CPU: ROS worker {many['rosworker_cpu']:.0%}, HTTP workers "
                 f"{many['http_cpu']:.0%}, the 2 readers {many['readers_cpu']:.0%} of a core; "
                 f"RSS: HTTP workers {many['rss_http_mb']:.0f} MiB, ROS worker {many['rss_rosworker_mb']:.0f} MiB",
                 f"≥ {t['streams_delivered']:.0%}, p50 ≤ {t['streams_lateness_p50_ms']:.0f} ms, "
                 f"p99 ≤ {t['streams_lateness_p99_ms']:.0f} ms, /health and warm p99 ≤ "
                 f"{t['streams_health_p99_ms']:.0f} ms, HTTP CPU ≤ {t['streams_http_us_per_frame']:.0f} µs/frame "
                 f"(measured {got['http_cpu_us_per_frame']:.0f})", passed)
        self.add("fanout", "stream fan-out cost", f"ROS worker CPU with {n} streams vs 10 streams on the same "
                 "10 topics, same window", {"many": many["rosworker_cpu"], "few": few["rosworker_cpu"]},
                 f"{many['rosworker_cpu']:.1%} vs {few['rosworker_cpu']:.1%} of a core = "
                 f"{got['fanout_ratio']:.2f} ×; HTTP side {got['http_cpu_us_per_frame']:.0f} µs CPU per "
                 "delivered frame", f"≤ {t['fanout_ratio']:g} ×", got["fanout_ratio"] <= t["fanout_ratio"])

    def case_stream_image(self) -> None:
        got = streams.case_image(self.gw, self.p["stream_image_s"])
        self.extra["stream_image"] = got
        target = streams.TARGETS["image_latency_p50_ms"]
        self.add("stream_image", "640×480 rgb8 at 5 Hz, streamed at fast",
                 "?bytes=base64, one SSE client; publish stamp (header.stamp) to the frame's last byte",
                 got, f"p50 {got['stamp_latency_p50_ms']:.1f} ms over {got['stamp_latency_n']} images "
                 f"= publish → tick p50 {got['stamp_to_tick_p50_ms']:.1f} ms (the cyclic design: the latest "
                 f"value waits for its topic's next tick, phased to its arrivals) + tick → arrival p50 {got['lateness_p50_ms']:.1f} ms "
                 f"(take, convert, IPC, HTTP, client); reference, same images, same run: DDS alone (an rclpy "
                 f"callback) p50 {got['dds']['p50_ms']:.1f} ms", f"p50 ≤ {target:.0f} ms (rosbridge: 146 ms)",
                 got["stamp_latency_p50_ms"] <= target)

    def case_sub_costs(self) -> None:
        n, seconds = self.p["made_up"], self.p["made_up_s"]
        got = streams.case_made_up(self.gw, self.host_id, n, seconds)
        self.extra["made_up"] = got
        extra = streams.TARGETS["made_up_cpu_extra"]
        self.add("made_up", f"{n} fast subscriptions on made-up topics",
                 f"ROS worker CPU over {seconds:g} s with {n} subscriptions at fast on topics nobody publishes "
                 "(no stream open), after the same worker holding none for as long",
                 got, f"{got['made_up_cpu']:.1%} of a core (reference, none held: {got['idle_cpu']:.1%}); "
                 "issue 18 measured 98 % before the fix", f"≤ idle + {extra:.0%} of a core",
                 got["extra_cpu"] <= extra)
        sizes, rounds = self.p["sub_sizes"], self.p["sub_rounds"]
        got = streams.case_sub_changes(self.gw, self.host_id, sizes, rounds)
        self.extra["sub_changes"] = got
        few, many = got[str(sizes[0])], got[str(sizes[-1])]
        extra_ms = streams.TARGETS["sub_change_extra_ms"]
        grown = max(many["post_p50_ms"] - few["post_p50_ms"], many["delete_p50_ms"] - few["delete_p50_ms"])
        self.add("sub_changes", f"subscription POST/DELETE at {sizes[0]} vs {sizes[-1]} held",
                 f"requests.Session, {rounds} POST + DELETE of one subscription (and a GET /version-info) at "
                 f"each size; median", got,
                 f"POST p50 {few['post_p50_ms']:.1f} → {many['post_p50_ms']:.1f} ms, DELETE p50 "
                 f"{few['delete_p50_ms']:.1f} → {many['delete_p50_ms']:.1f} ms (reference, no IPC: /version-info "
                 f"{few['floor_p50_ms']:.1f} → {many['floor_p50_ms']:.1f} ms); issue 18 measured POST 5.3 → 33.6 ms "
                 "before the fix", f"{sizes[-1]} ≤ {sizes[0]} + {extra_ms:g} ms", grown <= extra_ms)

    def case_cold(self) -> None:
        n = self.p["cold_n"]
        topics = [f"/bench/cold/t{i}" for i in range(n)]
        pub = robot("bench_cold", [{"prefix": "/bench/cold/t", "count": n, "rate": 10, "kind": "small"}])
        self.procs.append(pub)
        self.wait_topics(topics)
        # The HTTP workers' graph caches must know the host component (they do) and nothing else:
        # the topic is not checked against the entity.
        rng = random.Random(7)
        conn = http.client.HTTPConnection("127.0.0.1", self.gw.port, timeout=10)
        times, misses, reasons = [], 0, []
        for topic in topics:
            time.sleep(rng.uniform(0, 0.1))  # a random phase against the publisher's 10 Hz ticks
            path = self.url(topic)[len(self.gw.url):]
            start = time.perf_counter()
            conn.request("GET", path)
            resp = conn.getresponse()
            body = resp.read()
            elapsed = (time.perf_counter() - start) * 1000
            answer = json.loads(body)
            status = answer.get("x-medkit", {}).get("status") if resp.status == 200 else None
            if status == "data":
                times.append(round(elapsed, 3))
            else:
                misses += 1
                reasons.append(f"{resp.status} {answer.get('x-medkit', {}).get('reason') or answer.get('error_code')}"
                               f" after {elapsed:.0f} ms")
        conn.close()
        p50 = statistics.median(times) if times else float("inf")
        self.add("cold", "cold sample (first read of a fresh 10 Hz topic)",
                 f"http.client, {n} fresh topics read once each, random phase",
                 {"p50_ms": round(p50, 3), "max_ms": max(times, default=None), "min_ms": min(times, default=None),
                  "misses": misses, "miss_reasons": reasons, "samples_ms": times},
                 f"p50 {p50:.1f} ms (min {min(times, default=0):.1f}, max {max(times, default=0):.1f})"
                 + (f", {misses} without data ({'; '.join(reasons)})" if misses else ""),
                 f"p50 ≤ {TARGETS['cold_p50_ms']:.0f} ms", p50 <= TARGETS["cold_p50_ms"] and not misses)
        self.stop_proc(pub)
        self.evict_all()

    def case_idle(self) -> None:
        p = self.p
        n, rate = p["idle_topics"], p["idle_rate"]
        topics = [f"/bench/idle/t{i}" for i in range(n)]
        pub = robot("bench_idle", [{"prefix": "/bench/idle/t", "count": n, "rate": rate, "kind": "small"}])
        self.procs.append(pub)
        self.wait_topics(topics)
        self.evict_all()
        self.pool_topics(topics)
        floor = ros_helper("ddsfloor", json.dumps(topics), name="ddsfloor")
        self.procs.append(floor)
        time.sleep(2.0 if not self.args.quick else 1.0)  # matching settles
        pooled = self.call("pool")["topics"]
        worker = self.gw.rosworker()
        procs = {"rosworker": worker, "ddsfloor": psutil.Process(floor.pid),
                 "publisher": psutil.Process(pub.pid)}
        for i, w in enumerate(self.gw.http_workers()):
            procs[f"http_worker_{i}"] = w
        cpu = measure_cpu(procs, p["idle_s"])
        ratio = cpu["rosworker"] / cpu["ddsfloor"] if cpu["ddsfloor"] > 0 else float("inf")
        values = {k: round(v * 100, 2) for k, v in cpu.items()}
        values.update(pooled=len(pooled), topics=n, rate_hz=rate, seconds=p["idle_s"],
                      ratio=round(ratio, 3))
        self.add("idle", "idle cost: ROS worker CPU, 50 pooled topics × 100 Hz, no readers"
                 if n == 50 and rate == 100 else f"idle cost: {n} pooled topics × {rate} Hz",
                 f"psutil cpu_times over {p['idle_s']:g} s, same window as bench/ddsfloor.py "
                 f"({n} subscriptions held, never spun)",
                 values, f"worker {values['rosworker']:.1f}% of a core vs DDS floor "
                 f"{values['ddsfloor']:.1f}% = {ratio:.2f} × floor",
                 f"≤ {TARGETS['idle_cpu_ratio']} × floor", ratio <= TARGETS["idle_cpu_ratio"])
        self.stop_proc(floor)
        self.stop_proc(pub)
        self.evict_all()

    def case_memory(self) -> None:
        n = self.p["mem_topics"]
        topics = [f"/bench/mem/t{i}" for i in range(n)]
        worker = self.gw.rosworker()
        pub = robot("bench_memory", [{"prefix": "/bench/mem/t", "count": n, "rate": 2, "kind": "small"}],
                    timeout=120)
        self.procs.append(pub)
        self.wait_topics(topics, timeout=120)
        self.evict_all()
        time.sleep(0.5)
        before = worker.memory_info().rss
        self.pool_topics(topics, timeout=120)
        time.sleep(1.0)  # every pooled reader has a message (2 Hz)
        for t in topics:
            self.call("sample", {"topic": t, "timeout_ms": 2000}, timeout=5)
        after = worker.memory_info().rss
        pooled = len(self.call("pool")["topics"])
        per = (after - before) / max(1, pooled)
        values = {"rss_before_mib": round(before / 2**20, 1), "rss_after_mib": round(after / 2**20, 1),
                  "pooled": pooled, "per_topic_kib": round(per / 1024, 1)}
        self.add("memory", f"memory: ROS worker RSS with {n} pooled topics",
                 f"psutil RSS before pooling and after pooling + reading each of {n} topics once",
                 values, f"{values['rss_after_mib']:.1f} MiB with {pooled} pooled "
                 f"(from {values['rss_before_mib']:.1f} MiB: {values['per_topic_kib']:.0f} KiB/topic)")
        self.stop_proc(pub)
        self.evict_all()

    # ---- profiling ----
    def profile(self, warm_url: str) -> None:
        """py-spy (sampling, non-blocking) on the ROS worker and one HTTP worker under -c8 load."""
        spy = Path(sys.executable).parent / "py-spy"
        secs = max(3, int(self.p["load_s"]))
        out_dir = RESULTS
        targets = {"rosworker": self.gw.rosworker().pid, "http_worker": self.gw.http_workers()[0].pid}
        spies = []
        for name, pid in targets.items():
            path = out_dir / f"profile-{self.stamp}-{name}.txt"
            spies.append((name, path, subprocess.Popen(
                [str(spy), "record", "--nonblocking", "--threads", "-r", "250", "-d", str(secs + 1),
                 "--format", "raw", "-o", str(path), "-p", str(pid)],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)))
        time.sleep(0.5)
        self._load(warm_url, 8, secs)
        for name, path, proc in spies:
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
            self.extra.setdefault("profiles", {})[name] = str(path)
            log(f"py-spy profile of {name}: {path}")

    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")


def ros_helper_demo() -> Proc:
    proc = Proc([sys.executable, "-m", "demo.robot"], name="demo robot")
    proc.wait_line(lambda line: line.startswith("demo robot running"), 60)
    return proc


# ---------------------------------------------------------------------------- output

ORDER = ("floor8", "floor1", "warm8", "warm1", "echo8", "echo1", "hop1", "inside", "old", "cold", "image",
         "image_b64", "idle", "memory", "streams", "fanout", "stream_image", "made_up", "sub_changes",
         "trigger")


def ordered(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return sorted(rows, key=lambda r: ORDER.index(r["key"]) if r["key"] in ORDER else len(ORDER))


def table(rows: list[dict[str, Any]]) -> str:
    head = ("case", "how", "measured", "target", "result")
    body = [(r["case"], r["how"], r["measured"], r["target"], r["result"]) for r in rows]
    widths = [max(len(h), *(len(b[i]) for b in body)) for i, h in enumerate(head)]

    def line(cells):
        return "| " + " | ".join(c.ljust(w) for c, w in zip(cells, widths, strict=True)) + " |"
    out = [line(head), "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    out += [line(b) for b in body]
    return "\n".join(out)


def settings() -> dict[str, Any]:
    from common import settings as config
    cfg = config.load(None, environ={})
    info = {"workers": cfg.workers, "worker_connections": cfg.worker_connections,
            "sample_timeout": cfg.sample_timeout,
            "cold_wait_cap": cfg.cold_wait_cap, "max_pool_size": cfg.max_pool_size,
            "log_level": "warning (no access log)"}
    try:
        out = subprocess.run([sys.executable, "-c", "import app.gunicorn_conf as g; "
                              "print(g.worker_class, g.workers, g.worker_connections)"],
                             capture_output=True, text=True, timeout=30, env={**os.environ, "SOVD_LOG_LEVEL": "warning"})
        cls, workers, conns = out.stdout.split()
        info.update(worker_class=cls, workers=int(workers), worker_connections=int(conns))
    except (ValueError, OSError, subprocess.SubprocessError):
        pass
    return info


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.run", description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="every case, briefly (smoke test)")
    parser.add_argument("--out", default=str(RESULTS), help="directory for the JSON result")
    parser.add_argument("--no-install", action="store_true", help="do not install wrk when it is missing")
    parser.add_argument("--python-load", action="store_true", help="use the Python load generator, not wrk")
    parser.add_argument("--profile", action="store_true", help="also record py-spy profiles under load")
    parser.add_argument("--gateway-args", default="", metavar="ARGS",
                        help="extra sovd-gateway flags, e.g. '--workers 3' (recorded in the JSON)")
    parser.add_argument("--rounds", type=int, help="floor/warm rounds (default 3, quick 1)")
    parser.add_argument("--only", metavar="CASES", help="comma-separated subset of: warm (floor, warm "
                        "sample and echo route), old, memory, image, cold, idle, streams, stream_image, sub_costs, operations, params, rosout, faults, fleet, auth, write_checks, bulk_data, wake_idle, triggers (for "
                        "development; the table is "
                        "partial)")
    args = parser.parse_args(argv)

    bench = Bench(args)
    started = dt.datetime.now(dt.UTC)
    failed = None
    try:
        bench.start()
        bench.run_cases()
    except Exception as exc:  # noqa: BLE001 - report, still write what was measured
        failed = f"{type(exc).__name__}: {exc}"
        log(f"FAILED: {failed}")
    finally:
        bench.stop()

    result = {
        "started_at": started.isoformat(timespec="seconds"),
        "seconds": round((dt.datetime.now(dt.UTC) - started).total_seconds(), 1),
        "mode": "quick" if args.quick else "full",
        "host": {"cpus": os.cpu_count(), "python": platform.python_version(), "kernel": platform.release(),
                 "machine": platform.machine()},
        "load_generator": bench.load.name if bench.load else None,
        "load_generator_note": bench.load.note if bench.load else None,
        "gateway": {**settings(), "extra_args": args.gateway_args},
        "ros_domain_id": int(os.environ.get("ROS_DOMAIN_ID", "0")),
        "cases": ordered(bench.rows),
        "details": bench.extra,
        "error": failed,
        "all_targets_met": failed is None and all(r["result"] != "FAIL" for r in bench.rows),
    }
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"bench-{Bench.stamp}{'-quick' if args.quick else ''}.json"
    path.write_text(json.dumps(result, indent=1, default=str) + "\n")

    print()
    print(f"sovd-gateway bench ({result['mode']}), {result['started_at']}, {os.cpu_count()} CPUs, "
          f"load generator: {result['load_generator']}"
          + (f" ({result['load_generator_note']})" if result["load_generator_note"] else ""))
    g = result["gateway"]
    print(f"gateway: gunicorn {g.get('worker_class', '?')} × {g.get('workers')} workers × "
          f"{g.get('worker_connections')} connections, {g['log_level']}")
    print()
    print(table(ordered(bench.rows)))
    print()
    if failed:
        print(f"bench did not finish: {failed}")
    print(f"written to {path}")
    if failed is not None:
        return 1
    return 0 if result["all_targets_met"] or args.quick else 2


if __name__ == "__main__":
    sys.exit(main())
