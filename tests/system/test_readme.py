"""The README's examples, run against ``make run``'s demo as a new user runs them.

A shell block of the README whose fence says ``sh demo`` runs against the demo; the block right
after it, fenced ``text output``, is the shape of what it prints.  Both render as ordinary
``sh`` and ``text`` blocks on GitHub (it reads the first word of a fence only)::

    ```sh demo
    curl -s http://127.0.0.1:8080/api/v1/apps/temp_sensor/logs?severity=warning
    ```
    ```text output
    {"items":[…{"severity":"warning","message":"engine temperature high: … °C",…}…]}
    ```

A block passes when it exits 0 (it runs under ``bash -e``) and its standard output has that
shape: each line of the expectation matches a whole line of the output, in order (lines of the
output may come between); in a line, ``…`` stands for any text and everything else is itself.
A fence may also name what the demo needs for the block, ``sh demo ARGS=--allow-fault-clear``:
the demo is started once, with every block's ARGS.

The demo is started the way ``make run`` starts it (``make run BIND=… ARGS=…``), on a port of its
own, with its state, runtime dir and logs in a temporary ``--var`` (the test session's ROS domain
is private: tests/conftest.py).  In the blocks, ``127.0.0.1:8080`` and ``localhost:8080`` become
its address and ``demo/var/`` its directory.  Blocks run in the README's order, from the checkout.
"""

from __future__ import annotations

import dataclasses
import os
import re
import shlex
import signal
import subprocess
import tempfile
from pathlib import Path

import pytest
import requests

from common.harness.procs import REPO, free_port, poll_until

README = REPO / "README.md"
FENCE = re.compile(r"^(`{3,})([^`]*)$")   # CommonMark: no backtick in a fence's info string
BLOCK_TIMEOUT = 120      # seconds one block may take (the slowest wait for the demo's 30 s cycles)
pytestmark = pytest.mark.timeout(400)   # the first block also waits for the demo to start


@dataclasses.dataclass
class Block:
    line: int                 # where its fence is in the README (1-based)
    code: str
    expect: list[str] | None  # the lines of its ``text output`` block, if it has one
    args: list[str]           # what the demo needs for it (ARGS=... in its fence)

    @property
    def name(self) -> str:
        first = next((ln for ln in self.code.splitlines() if ln.strip() and not ln.startswith("#")), "")
        return f"line {self.line}: {first.strip()[:70]}"


def parse(text: str) -> list[Block]:
    """The ``sh demo`` blocks of a markdown text, each with the ``text output`` block right after it."""
    lines = text.splitlines()
    fences = []  # (line index, info, body lines, end index)
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        close = re.compile(f"^{m.group(1)}`*\\s*$")
        end = next((j for j in range(i + 1, len(lines)) if close.match(lines[j])), None)
        if end is None:
            raise ValueError(f"README line {i + 1}: a fence that is never closed")
        fences.append((i, m.group(2).split(), lines[i + 1:end], end))
        i = end + 1
    blocks = []
    for k, (start, info, body, end) in enumerate(fences):
        if info[:2] != ["sh", "demo"]:
            continue
        expect = None
        if k + 1 < len(fences):
            nstart, ninfo, nbody, _ = fences[k + 1]
            if ninfo[:2] == ["text", "output"] and all(not ln.strip() for ln in lines[end + 1:nstart]):
                expect = [ln for ln in nbody if ln.strip()]
        args = [a for word in info[2:] if word.startswith("ARGS=") for a in shlex.split(word[5:])]
        blocks.append(Block(start + 1, "\n".join(body), expect, args))
    return blocks


def pattern(line: str) -> re.Pattern:
    """One expectation line: ``…`` is any text, the rest is itself."""
    return re.compile(".*?".join(re.escape(part) for part in line.strip().split("…")), re.DOTALL)


def mismatch(output: str, expect: list[str]) -> str | None:
    """None when ``output`` has the shape of ``expect``; else which line was not found."""
    got = [ln.strip() for ln in output.splitlines()]
    at = 0
    for want in expect:
        rx = pattern(want)
        while at < len(got) and not rx.fullmatch(got[at]):
            at += 1
        if at == len(got):
            return f"no line of the output (after those matched before) has the shape {want.strip()!r}"
        at += 1
    return None


def adapt(code: str, port: int, var: Path) -> str:
    """The block as it runs against the test's demo: its address and its directory."""
    code = code.replace("127.0.0.1:8080", f"127.0.0.1:{port}").replace("localhost:8080", f"127.0.0.1:{port}")
    return code.replace("demo/var/", f"{var}/")


@dataclasses.dataclass
class Demo:
    port: int
    var: Path
    proc: subprocess.Popen

    @property
    def api(self) -> str:
        return f"http://127.0.0.1:{self.port}/api/v1"


def run(block: Block, demo: Demo) -> tuple[subprocess.CompletedProcess, str | None]:
    """Run one block; (its result, why it fails or None)."""
    r = subprocess.run(["bash", "-e", "-c", adapt(block.code, demo.port, demo.var)], cwd=REPO, text=True,
                       capture_output=True, timeout=BLOCK_TIMEOUT, stdin=subprocess.DEVNULL)
    if r.returncode != 0:
        return r, f"exit code {r.returncode}"
    if block.expect is None:
        return r, "no `text output` block after it"
    return r, mismatch(r.stdout, block.expect)


BLOCKS = parse(README.read_text())


def _demo_ready(demo: Demo) -> bool:
    """What the examples read from the start: the demo's apps, the battery's and the wheel's faults kept,
    the engine's warnings and the wheel's errors logged."""
    apps = {a["id"] for a in requests.get(demo.api + "/apps", timeout=5).json()["items"]}
    if not {"temp_sensor", "odometry", "battery_monitor", "calibration", "controller"} <= apps:
        return False
    kept = {f["fault_code"] for f in requests.get(demo.api + "/faults?status=all", timeout=5).json()["items"]}
    if not {"BATTERY_MONITOR_BATTERY", "ODOMETRY_WHEEL_SLIP"} <= kept:
        return False
    for app, severity in (("temp_sensor", "warning"), ("odometry", "error")):
        if not requests.get(f"{demo.api}/apps/{app}/logs?severity={severity}", timeout=5).json()["items"]:
            return False
    sample = requests.get(demo.api + "/apps/temp_sensor/data/powertrain/engine/temperature", timeout=5).json()
    return sample["x-medkit"]["status"] == "data"


@pytest.fixture(scope="module")
def demo():
    port = free_port()
    var = Path(tempfile.mkdtemp(prefix="sovd-readme-"))
    args = sorted({a for b in BLOCKS for a in b.args})
    # `make run`, as the README says to start it (-o: the install it depends on is taken as made).
    proc = subprocess.Popen(["make", "-s", "-o", ".venv/.installed", "run", f"BIND=127.0.0.1:{port}",
                             "ARGS=" + shlex.join(["--var", str(var), *args])],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    running = Demo(port, var, proc)
    try:
        poll_until(lambda: proc.poll() is None and _demo_ready(running), 120, interval=0.5,
                   message="the demo's apps, faults and log lines")
        yield running
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate(timeout=10)


def test_the_readme_has_examples_that_run_on_the_demo():
    assert len(BLOCKS) >= 15, [b.name for b in BLOCKS]   # every resource family has its examples
    assert not [b.name for b in BLOCKS if b.expect is None], "sh demo blocks without a `text output` block"


@pytest.mark.parametrize("block", BLOCKS, ids=lambda b: f"L{b.line}")
def test_a_readme_example(demo, block):
    r, problem = run(block, demo)
    assert problem is None, (f"README {block.name} fails: {problem}\n--- block as run:\n"
                             f"{adapt(block.code, demo.port, demo.var)}\n--- stdout:\n{r.stdout[-4000:]}\n"
                             f"--- stderr:\n{r.stderr[-2000:]}\n--- expected shape:\n" + "\n".join(block.expect or []))


# ---- the checker itself: it catches a broken block ----------------------------------------------
def test_the_shape_check():
    expect = ['{"items":[…{"id":"temp_sensor",…}…]}', "done"]
    assert mismatch('{"items":[{"id":"a"},{"id":"temp_sensor","x":1}]}\nnoise\ndone\n', expect) is None
    assert mismatch('{"items":[]}\ndone\n', expect) is not None                      # the item is missing
    assert mismatch('done\n{"items":[{"id":"temp_sensor"}]}\n', expect) is not None  # out of order
    assert mismatch('{"items":[{"id":"temp_sensor"}]}', expect) is not None           # a line is missing
    assert mismatch('x{"items":[{"id":"temp_sensor"}]}\ndone', expect) is not None    # a whole line, not a part
    text = "```sh demo ARGS=--allow-fault-clear\ncurl x\n```\n\n```text output\nabc…\n```\n```sh\nls\n```\n"
    (block,) = parse(text)
    assert (block.line, block.code, block.expect, block.args) == (1, "curl x", ["abc…"], ["--allow-fault-clear"])


def test_a_broken_block_is_caught(demo):
    """A real example broken three ways, as the README could drift: each run fails, and says why."""
    block = next(b for b in BLOCKS if "apps/temp_sensor/logs" in b.code)
    assert run(block, demo)[1] is None
    # The code names an app the demo does not have (the README named apps of another robot once).
    wrong_app = dataclasses.replace(block, code=block.code.replace("temp_sensor", "battery_driver"))
    assert "has the shape" in run(wrong_app, demo)[1]
    # The code fails (an option curl does not have): exit code, whatever it printed.
    failing = dataclasses.replace(block, code=block.code.replace("curl -s", "curl --no-such-option -s", 1))
    assert run(failing, demo)[1].startswith("exit code")
    # The output drifted from what the README shows (a field that was renamed, say).
    drifted = dataclasses.replace(block, expect=[line.replace('"severity"', '"level"') for line in block.expect])
    assert "has the shape" in run(drifted, demo)[1]
    # A block whose expectation is missing is not a passing block.
    assert run(dataclasses.replace(block, expect=None), demo)[1] == "no `text output` block after it"
