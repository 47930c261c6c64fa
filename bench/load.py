"""HTTP load: ``wrk`` when it is there, else a documented Python fallback.

``wrk`` (Debian's package) runs with one thread and ``-c N`` keep-alive
connections on the loopback; a Lua ``done`` hook prints its summary as JSON:
requests, duration, errors (non-2xx answers count as ``status`` errors) and
latency percentiles from wrk's own histogram (microsecond resolution), so
the p50 of a 1-connection run is the median request time as wrk saw it.

The fallback (``python -m bench.load URL CONNECTIONS SECONDS``, started as
two processes so that one GIL does not cap it) keeps one ``http.client``
keep-alive connection per thread and times every request with
``time.perf_counter``.  It is slower than wrk and uses more CPU, so its
throughput figures are lower bounds; floor and gateway are always measured
with the same generator, so the ratios stay comparable.
"""

from __future__ import annotations

import http.client
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse

WRK_LUA = r"""
done = function(summary, latency, requests)
  io.write(string.format('BENCHJSON {"requests":%d,"duration_us":%d,"bytes":%d,' ..
    '"errors":{"connect":%d,"read":%d,"write":%d,"status":%d,"timeout":%d},' ..
    '"latency_us":{"min":%d,"mean":%.1f,"p50":%d,"p90":%d,"p99":%d,"max":%d}}\n',
    summary.requests, summary.duration, summary.bytes, summary.errors.connect,
    summary.errors.read, summary.errors.write, summary.errors.status, summary.errors.timeout,
    latency.min, latency.mean, latency:percentile(50), latency:percentile(90),
    latency:percentile(99), latency.max))
end
"""


def find_wrk() -> str | None:
    return shutil.which("wrk") or (("/usr/bin/wrk") if os.access("/usr/bin/wrk", os.X_OK) else None)


def ensure_wrk(install: bool) -> tuple[str | None, str]:
    """``(path or None, note)``: wrk, installed from Debian when missing and allowed."""
    path = find_wrk()
    if path or not install:
        return path, "" if path else "wrk not found (install not attempted)"
    if os.geteuid() != 0 and not shutil.which("sudo"):
        return None, "wrk not found and not root: cannot install it"
    sudo = [] if os.geteuid() == 0 else ["sudo", "-n"]
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    try:
        for argv in (["apt-get", "update", "-qq"], ["apt-get", "install", "-y", "-qq", "wrk"]):
            subprocess.run(sudo + argv, env=env, check=True, timeout=300,
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    except (OSError, subprocess.SubprocessError) as exc:
        return None, f"wrk could not be installed from Debian ({type(exc).__name__})"
    path = find_wrk()
    return path, "installed wrk from Debian" if path else "apt-get ran but wrk is still missing"


def wrk_version(path: str) -> str:
    try:
        out = subprocess.run([path, "--version"], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return "wrk"
    text = (out.stdout or out.stderr).strip().splitlines()
    return text[0].split(" Copyright")[0] if text else "wrk"


class LoadResult(dict):
    """``requests, seconds, rps, errors, p50_ms, p90_ms, p99_ms, mean_ms, bytes_per_request``."""


def run_wrk(wrk: str, url: str, connections: int, seconds: float, headers: dict[str, str] | None = None) -> LoadResult:
    with tempfile.NamedTemporaryFile("w", suffix=".lua", delete=False) as fh:
        # headers (a bearer token) go in the script, not on a command line that ps shows
        fh.write("".join(f"wrk.headers[{json.dumps(k)}] = {json.dumps(v)}\n" for k, v in (headers or {}).items()))
        fh.write(WRK_LUA)
        script = fh.name
    try:
        argv = [wrk, "-t1", f"-c{connections}", f"-d{max(1, round(seconds))}s", "--timeout", "10s",
                "-s", script, url]
        out = subprocess.run(argv, capture_output=True, text=True, timeout=seconds + 60)
    finally:
        os.unlink(script)
    line = next((x for x in out.stdout.splitlines() if x.startswith("BENCHJSON ")), None)
    if line is None:
        raise RuntimeError(f"wrk printed no summary (exit {out.returncode}): {out.stdout[-500:]} "
                           f"{out.stderr[-500:]}")
    raw = json.loads(line[len("BENCHJSON "):])
    lat = raw["latency_us"]
    secs = raw["duration_us"] / 1e6
    n = raw["requests"]
    return LoadResult(
        requests=n, seconds=round(secs, 3), rps=round(n / secs, 1) if secs else 0.0,
        errors=sum(raw["errors"].values()), error_kinds={k: v for k, v in raw["errors"].items() if v},
        p50_ms=lat["p50"] / 1000, p90_ms=lat["p90"] / 1000,
        p99_ms=lat["p99"] / 1000, mean_ms=round(lat["mean"] / 1000, 3),
        bytes_per_request=round(raw["bytes"] / n) if n else 0,
    )


# ---------------------------------------------------------------------------- Python fallback

HEADERS_ENV = "SOVD_BENCH_HEADERS"   # the fallback's request headers, as JSON (not on its command line)


def _worker(url: str, seconds: float, out: list, errors: list, stop_at: float) -> None:
    parts = urllib.parse.urlsplit(url)
    path = parts.path + ("?" + parts.query if parts.query else "")
    headers = json.loads(os.environ.get(HEADERS_ENV) or "{}")
    conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=10)
    times, nbytes = [], 0
    while time.perf_counter() < stop_at:
        start = time.perf_counter()
        try:
            conn.request("GET", path, headers=headers)
            resp = conn.getresponse()
            body = resp.read()
        except (OSError, http.client.HTTPException):
            errors.append(1)
            conn.close()
            conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=10)
            continue
        times.append(time.perf_counter() - start)
        nbytes += len(body)
        if resp.status >= 400:
            errors.append(1)
    conn.close()
    out.append((times, nbytes))


def _pyload_main(url: str, connections: int, seconds: float) -> None:
    """One fallback process: ``connections`` threads; prints its raw times as JSON."""
    out: list = []
    errors: list = []
    stop_at = time.perf_counter() + seconds
    threads = [threading.Thread(target=_worker, args=(url, seconds, out, errors, stop_at))
               for _ in range(connections)]
    started = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join(seconds + 30)
    elapsed = time.perf_counter() - started
    times = [x for chunk, _ in out for x in chunk]
    print("BENCHJSON " + json.dumps({"times": times, "bytes": sum(b for _, b in out),
                                     "errors": len(errors), "seconds": elapsed}), flush=True)


def run_python(url: str, connections: int, seconds: float, headers: dict[str, str] | None = None) -> LoadResult:
    procs = min(2, connections)
    split = [connections // procs + (1 if i < connections % procs else 0) for i in range(procs)]
    env = {**os.environ, HEADERS_ENV: json.dumps(headers or {})}
    children = [subprocess.Popen([sys.executable, "-m", "bench.load", url, str(n), str(seconds)],
                                 stdout=subprocess.PIPE, text=True, env=env) for n in split]
    times: list[float] = []
    nbytes = errors = 0
    secs = 0.0
    for child in children:
        stdout, _ = child.communicate(timeout=seconds + 60)
        line = next((x for x in stdout.splitlines() if x.startswith("BENCHJSON ")), None)
        if line is None:
            raise RuntimeError("the Python load generator printed no summary")
        raw = json.loads(line[len("BENCHJSON "):])
        times += raw["times"]
        nbytes += raw["bytes"]
        errors += raw["errors"]
        secs = max(secs, raw["seconds"])
    return summarize(times, secs, errors, nbytes)


def summarize(times: list[float], seconds: float, errors: int = 0, nbytes: int = 0) -> LoadResult:
    n = len(times)
    ms = sorted(t * 1000 for t in times)

    def pct(p: float) -> float:
        return round(ms[min(n - 1, int(p / 100 * n))], 3) if n else 0.0

    return LoadResult(
        requests=n, seconds=round(seconds, 3), rps=round(n / seconds, 1) if seconds else 0.0,
        errors=errors, p50_ms=round(statistics.median(ms), 3) if n else 0.0, p90_ms=pct(90),
        p99_ms=pct(99), mean_ms=round(statistics.fmean(ms), 3) if n else 0.0,
        bytes_per_request=round(nbytes / n) if n else 0,
    )


class Load:
    """The load generator chosen for this run: ``run(url, connections, seconds)``."""

    def __init__(self, wrk: str | None, note: str = ""):
        self.wrk = wrk
        self.note = note
        self.name = wrk_version(wrk) if wrk else "python http.client fallback (bench/load.py)"

    def run(self, url: str, connections: int, seconds: float, headers: dict[str, str] | None = None) -> LoadResult:
        if self.wrk:
            return run_wrk(self.wrk, url, connections, seconds, headers)
        return run_python(url, connections, seconds, headers)


if __name__ == "__main__":
    _pyload_main(sys.argv[1], int(sys.argv[2]), float(sys.argv[3]))
