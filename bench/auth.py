"""Issue 31's bench rows: what checking who is acting costs, each against the same thing without it,
in the same run.

- ``auth``: the warm sample (``GET …/data/powertrain/engine/temperature``, the demo's 10 Hz
  Temperature) through a gateway with ``--auth-enabled --require-auth-for all`` (a viewer's JWT on
  every request: the token, its revocation and the role checked each time) against the same read
  through the bench's gateway without authentication, in alternating rounds, 8 connections and 1.
  Target: throughput ≥ 1/1.05 × and 1-connection p50 ≤ 1.05 × without (medians of the paired rounds).
- ``write_checks``: a publish (``PUT /apps/controller/data/body/lights/cmd``, the demo's lights
  command) through a gateway with its lock check (a lock held on another app, so the check reads a
  table that is not empty) and its audit record, against the same publish through a gateway with
  ``--no-locking-enabled --audit-max-records 0``; 1 connection (``requests``), alternating blocks.
  Target: p50 ≤ without + 0.3 ms.  The audit records written during the run are counted, so the row
  shows that the path measured is the audited one.

Both start their own gateways beside the bench's (``bench/run.py``) on the same demo robot.
"""

from __future__ import annotations

import statistics
import time

import requests

from common.harness.gateway import Gateway
from common.harness.procs import poll_until

WARM = "/apps/temp_sensor/data/powertrain/engine/temperature"
WRITE = "/apps/controller/data/body/lights/cmd"
MESSAGE = {"type": "std_msgs/msg/Bool", "data": {"data": True}}
SECRET = "bench-jwt-secret-0123456789-0123456789"
CLIENTS = "viewer:bench-viewer-secret:viewer,admin:bench-admin-secret:admin"
LEGACY = "bench-legacy-admin-token-0123"
RATIO = 1.05
WRITE_EXTRA_MS = 0.3


def _gateway(bench, *args: str, env: dict | None = None, name: str) -> Gateway:
    import os

    return Gateway("--log-level", "warning", *args, env=env, log_path=os.path.join(bench.work_dir, f"{name}.log"))


def case_auth(bench) -> None:
    p = bench.p
    env = {"SOVD_AUTH_CLIENTS": CLIENTS, "SOVD_JWT_SECRET": SECRET, "SOVD_API_TOKEN": LEGACY}
    gw = _gateway(bench, "--debug-commands", "--allow-operations", "--auth-enabled", "--require-auth-for", "all",
                  env=env, name="gateway-auth-all")
    try:
        granted = requests.post(gw.api + "/auth/authorize", json={"grant_type": "client_credentials", "client_id": "viewer",
                                                                  "client_secret": "bench-viewer-secret"}, timeout=10)
        headers = {"Authorization": f"Bearer {granted.json()['access_token']}"}
        plain_url, auth_url = bench.gw.api + WARM, gw.api + WARM
        bench.wait_data(plain_url)
        poll_until(lambda: requests.get(auth_url, headers=headers, timeout=10).json()["x-medkit"]["status"] == "data",
                   60, interval=0.1, message="the warm sample through the gateway with auth all")
        if p["warmup_s"]:
            bench.load.run(plain_url, 8, p["warmup_s"])
            bench.load.run(auth_url, 8, p["warmup_s"], headers)
        ratios8, ratios1, runs = [], [], {"plain8": [], "auth8": [], "plain1": [], "auth1": []}
        for i in range(p["rounds"]):
            for key, url, conns, extra in (("plain8", plain_url, 8, None), ("auth8", auth_url, 8, headers),
                                           ("plain1", plain_url, 1, None), ("auth1", auth_url, 1, headers)):
                result = bench.load.run(url, conns, p["load_s"], extra)
                assert result["errors"] == 0 or bench.args.quick, (key, result)
                runs[key].append(result)
            ratios8.append(runs["plain8"][-1]["rps"] / runs["auth8"][-1]["rps"] if runs["auth8"][-1]["rps"] else 99.0)
            ratios1.append(runs["auth1"][-1]["p50_ms"] / runs["plain1"][-1]["p50_ms"] if runs["plain1"][-1]["p50_ms"]
                           else 99.0)
            bench_log(f"auth round {i + 1}: -c8 {runs['plain8'][-1]['rps']:.0f} vs {runs['auth8'][-1]['rps']:.0f} req/s, "
                      f"-c1 p50 {runs['plain1'][-1]['p50_ms']:.3f} vs {runs['auth1'][-1]['p50_ms']:.3f} ms")
    finally:
        gw.stop()
    r8, r1 = statistics.median(ratios8), statistics.median(ratios1)
    med = {k: {"rps": statistics.median(r["rps"] for r in v), "p50_ms": statistics.median(r["p50_ms"] for r in v)}
           for k, v in runs.items()}
    bench.add("auth", "warm sample with auth `all` (a JWT checked on every request)",
              f"GET …/data{WARM.split('/data', 1)[1]} through a gateway with --auth-enabled --require-auth-for all "
              f"(a viewer's token) against the bench's gateway without, {p['rounds']} alternating rounds",
              {**med, "slowdown_8": round(r8, 3), "slowdown_1": round(r1, 3), "paired_8": [round(x, 3) for x in ratios8],
               "paired_1": [round(x, 3) for x in ratios1]},
              f"-c8 {med['auth8']['rps']:.0f} vs {med['plain8']['rps']:.0f} req/s ({r8:.3f} ×); -c1 p50 "
              f"{med['auth1']['p50_ms']:.3f} vs {med['plain1']['p50_ms']:.3f} ms ({r1:.3f} ×)",
              f"≤ {RATIO} × without", r8 <= RATIO and r1 <= RATIO)


def case_write(bench) -> None:
    n, block = (10, 5) if bench.args.quick else (600, 50)
    checked = _gateway(bench, "--allow-publish", env={"SOVD_API_TOKEN": LEGACY}, name="gateway-checked")
    plain = _gateway(bench, "--allow-publish", "--no-locking-enabled", "--audit-max-records", "0", name="gateway-plain")
    admin = {"Authorization": f"Bearer {LEGACY}"}
    try:
        sessions = {"checked": requests.Session(), "plain": requests.Session()}
        gateways = {"checked": checked, "plain": plain}
        for key, gw in gateways.items():
            poll_until(lambda gw=gw, key=key: sessions[key].put(gw.api + WRITE, json=MESSAGE, headers=admin,
                                                                 timeout=10).status_code == 200,
                       60, interval=0.2, message=f"the demo's lights command through the {key} gateway")
        # a lock on another app: the check of each write reads a table that holds one
        r = sessions["checked"].post(checked.api + "/apps/odometry/locks", json={"lock_expiration": 3600},
                                     headers={**admin, "X-Client-Id": "someone-else"}, timeout=10)
        assert r.status_code == 201, r.text
        before = _audit_count(checked, admin)
        samples: dict[str, list[float]] = {"checked": [], "plain": []}
        done = 0
        while done < n:
            for key in ("plain", "checked"):
                gw, session = gateways[key], sessions[key]
                for _ in range(block):
                    t0 = time.perf_counter()
                    r = session.put(gw.api + WRITE, json=MESSAGE, headers=admin, timeout=10)
                    samples[key].append((time.perf_counter() - t0) * 1000)
                    assert r.status_code == 200, r.text
            done += block
        poll_until(lambda: _audit_count(checked, admin) >= before + n, 10, message="every publish audited")
        audited = _audit_count(checked, admin) - before
    finally:
        checked.stop()
        plain.stop()
    c50, p50 = statistics.median(samples["checked"]), statistics.median(samples["plain"])
    extra = c50 - p50
    bench.add("write_checks", "a write with its lock check and audit record",
              f"PUT {WRITE} (std_msgs/Bool), 1 connection, {n} each in alternating blocks of {block}: a gateway "
              "with locking (a lock held on another app) and the audit trail against one with neither",
              {"checked_p50_ms": round(c50, 3), "plain_p50_ms": round(p50, 3), "extra_ms": round(extra, 3),
               "audited": audited, "n": n},
              f"p50 {c50:.3f} vs {p50:.3f} ms (+{extra:.3f} ms); {audited} audit records written",
              f"≤ without + {WRITE_EXTRA_MS} ms", extra <= WRITE_EXTRA_MS)


def _audit_count(gw: Gateway, admin: dict) -> int:
    """How many audit records the gateway holds (at most 1000 counted: more than the run writes)."""
    return len(requests.get(gw.api + "/x-medkit-audit", params={"limit": 1000}, headers=admin, timeout=10)
               .json()["items"])


def bench_log(text: str) -> None:
    from .run import log

    log(text)
