"""supervisor/limits.py: the open-file limit is raised where the gateway starts (issue 23).

Every SSE stream holds a connection: a gateway started under the common soft
limit of 1,024 descriptors would refuse streams past about a thousand.  The
supervisor raises its soft limit to the hard one, and its children inherit it.
"""

from __future__ import annotations

import resource
import subprocess
import sys

import psutil

from common.harness.gateway import Gateway


def test_the_gateway_and_its_children_run_with_the_hard_limit():
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    low = min(soft, 512, hard)
    resource.setrlimit(resource.RLIMIT_NOFILE, (low, hard))   # the gateway starts under a low soft limit
    try:
        gw = Gateway("--workers", "2", "--log-level", "warning")
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
    try:
        procs = [psutil.Process(gw.pid), gw.rosworker(), *gw.http_workers()]
        assert len(procs) == 4
        for proc in procs:
            assert proc.rlimit(psutil.RLIMIT_NOFILE) == (hard, hard), (proc.cmdline()[:3], hard)
    finally:
        gw.stop()


def test_raise_nofile_keeps_a_limit_it_cannot_raise_and_reports_it():
    """In a child process whose hard limit is its soft one: nothing to raise, nothing fails."""
    code = ("import resource; from supervisor.limits import raise_nofile; "
            "resource.setrlimit(resource.RLIMIT_NOFILE, (300, 300)); print(raise_nofile())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30, check=True)
    assert out.stdout.strip() == "(300, 300)", out
