"""``make run``: the demo robot and the gateway in the foreground; Ctrl-C stops both.

    python -m demo.run [--bind HOST:PORT] [--var DIR] [any sovd-gateway flag ...]

The demo keeps everything it writes in a directory of its own, ``demo/var/`` in the checkout
(``--var`` names another; git ignores it), never in the user's own places:

    demo/var/state/      the gateway's state dir (the fault store, faults.db): this demo's faults only
    demo/var/run/        the gateway's runtime dir (its sockets: sovd-probe --runtime-dir demo/var/run)
    demo/var/robot.log   the demo robot's output (its ROS log lines), instead of the terminal
    demo/var/ros-log/    ROS 2's own log files (ROS_LOG_DIR), instead of ~/.ros/log

``--state-dir`` or ``--runtime-dir`` among the gateway's flags win over these.  Discovery stays on
this host (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) unless the environment says otherwise.  Once
the gateway answers, a banner says where the dashboard, the health route and each of these are.

Both run in process groups of their own (as the gateway's own children do), so Ctrl-C in the
terminal reaches only this launcher, which then stops each of them once, in order; a second signal
would make the gateway skip its ordered stop.  They die with the launcher if it is killed outright.
"""

from __future__ import annotations

import argparse
import http.client
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from supervisor.children import Child

BIN = Path(sys.executable).parent
CHECKOUT = Path(__file__).resolve().parents[1]
VAR = CHECKOUT / "demo" / "var"
# The gateway's sockets live in its runtime dir; a unix socket's path has at most 107 bytes.
SOCKET_PATH_MAX = 100
LONGEST_SOCKET = "rosworker-events.sock"
READY_WAIT = 90.0   # seconds the banner waits for the gateway's first answer


DEMO_RECORDED = "/powertrain/engine/temperature,/chassis/brakes/pressure,/chassis/odom,/power/battery"


def parse(argv: list[str] | None = None) -> tuple[argparse.Namespace, list[str]]:
    parser = argparse.ArgumentParser(description="Run the demo robot and the gateway together; "
                                                 "any other flag goes to sovd-gateway.")
    parser.add_argument("--bind", default="127.0.0.1:8080")
    parser.add_argument("--var", default=str(VAR), help="where the demo keeps its state, sockets and logs "
                                                        "(default: demo/var in the checkout)")
    parser.add_argument("--state-dir", help="the gateway's state dir (default: VAR/state)")
    parser.add_argument("--runtime-dir", help="the gateway's runtime dir (default: VAR/run)")
    return parser.parse_known_args(argv)


def runtime_dir(var: Path) -> Path:
    """VAR/run, or a private dir under the temp dir when VAR's path is too long for a socket's."""
    wanted = var / "run"
    if len(str(wanted / LONGEST_SOCKET).encode()) <= SOCKET_PATH_MAX:
        return wanted
    return Path(tempfile.mkdtemp(prefix="sovd-demo-run-"))


def answers(host: str, port: int) -> bool:
    conn = http.client.HTTPConnection(host, port, timeout=2)
    try:
        conn.request("GET", "/api/v1/health")
        return conn.getresponse().status == 200
    except (OSError, http.client.HTTPException):
        return False
    finally:
        conn.close()


def shown(path: Path) -> str:
    """A path as the banner shows it: relative to the working directory when it is inside it."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def banner(base: str, state: Path, run: Path, robot_log: Path) -> str:
    domain = os.environ.get("ROS_DOMAIN_ID") or "0"
    reach = "this host only" if os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") == "LOCALHOST" else \
        f"discovery range {os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE') or 'default'}"
    return "\n".join((
        "",
        "sovd-gateway demo is running",
        f"  dashboard    {base}/",
        f"  health       {base}/api/v1/health",
        f"  state dir    {shown(state)}   (faults.db: this demo's faults only)",
        f"  runtime dir  {shown(run)}   (.venv/bin/sovd-probe --runtime-dir {shown(run)} ping)",
        f"  robot log    {shown(robot_log)}   (the demo robot's ROS log lines)",
        f"  ROS domain   {domain}, {reach}",
        "Ctrl-C stops the gateway and the demo robot.",
        "",
    ))


def main(argv: list[str] | None = None) -> int:
    args, gateway_args = parse(argv)
    var = Path(args.var).resolve()
    state = Path(args.state_dir) if args.state_dir else var / "state"
    run = Path(args.runtime_dir) if args.runtime_dir else runtime_dir(var)
    robot_log = var / "robot.log"
    for path in (var, state):
        path.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "ROS_LOG_DIR": os.environ.get("ROS_LOG_DIR") or str(var / "ros-log")}
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env["ROS_AUTOMATIC_DISCOVERY_RANGE"]  # for the banner
    log = open(robot_log, "a", buffering=1)  # noqa: SIM115 - open while the robot runs
    log.write(f"--- demo robot started {time.strftime('%Y-%m-%d %H:%M:%S')} ---\n")
    robot = Child("demo robot", [sys.executable, "-m", "demo.robot"], env, signal.SIGTERM, output=log)
    # Publishing, operations and configurations are off by default; the demo turns them on so that
    # the README's examples work.  ARGS of `make run` add more (--allow-fault-clear, --api-token ...).
    # It records a few topics: a confirmed fault gets a recording of them (bulk data, issue 32).
    gateway = Child("sovd-gateway", [str(BIN / "sovd-gateway"), "--bind", args.bind, "--allow-publish",
                                     "--allow-operations", "--allow-configurations",
                                     "--fault-rosbag-enabled", "--fault-rosbag-topics", DEMO_RECORDED,
                                     "--state-dir", str(state), "--runtime-dir", str(run),
                                     *gateway_args], env, signal.SIGTERM)
    stopping = []
    signal.signal(signal.SIGINT, lambda *_: stopping.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stopping.append(1))
    robot.start()
    gateway.start()
    host, _, port = args.bind.rpartition(":")
    host = host.strip("[]")
    connect = "127.0.0.1" if host in ("", "0.0.0.0") else "::1" if host == "::" else host
    base = f"http://[{connect}]:{port}" if ":" in connect else f"http://{connect}:{port}"
    ready_by = time.monotonic() + READY_WAIT
    announced = False
    code = 0
    try:
        while not stopping and gateway.alive() and robot.alive():
            if not announced and answers(connect, int(port)):
                print(banner(base, state, run, robot_log), flush=True)
                announced = True
            elif not announced and time.monotonic() > ready_by:
                print(f"\nsovd-gateway demo: the gateway does not answer on {base} yet; its lines above say why. "
                      f"The robot's are in {shown(robot_log)}.\n", flush=True)
                announced = True
            try:
                gateway.proc.wait(timeout=0.5)
            except subprocess.TimeoutExpired:
                pass
        if not gateway.alive():
            code = gateway.returncode
        elif not robot.alive():
            print(f"sovd-gateway demo: the demo robot {robot.describe_exit()}; its output is in "
                  f"{shown(robot_log)}", flush=True)
            code = 1
    finally:
        for child in (gateway, robot):
            child.send(signal.SIGTERM)
        for child in (gateway, robot):
            try:
                child.proc.wait(timeout=12)
            except subprocess.TimeoutExpired:
                child.kill_group()
                child.proc.wait(timeout=5)
        log.close()
    return code


if __name__ == "__main__":
    sys.exit(main())
