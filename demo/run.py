"""``make run``: the demo robot and the gateway in the foreground; Ctrl-C stops both.

Both run in process groups of their own (as the gateway's own children do), so
Ctrl-C in the terminal reaches only this launcher, which then stops each of them
once, in order; a second signal would make the gateway skip its ordered stop.
They die with the launcher if it is killed outright.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
from pathlib import Path

from supervisor.children import Child

BIN = Path(sys.executable).parent


def main() -> int:
    parser = argparse.ArgumentParser(description="Run the demo robot and the gateway together.")
    parser.add_argument("--bind", default="127.0.0.1:8080")
    args, gateway_args = parser.parse_known_args()
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    robot = Child("demo robot", [sys.executable, "-m", "demo.robot"], env, signal.SIGTERM)
    # Publishing and operations are off by default; the demo turns them on so that the README's
    # PUT and operations examples work.
    gateway = Child("sovd-gateway", [str(BIN / "sovd-gateway"), "--bind", args.bind, "--allow-publish",
                                     "--allow-operations",
                                     "--allow-configurations",  # configurations: the README's PUT example
                                     *gateway_args], env, signal.SIGTERM)
    robot.start()
    gateway.start()
    host, _, port = args.bind.rpartition(":")
    print(f"\nsovd-gateway demo: try  curl http://{host}:{port}/api/v1/health\n"
          "Ctrl-C stops the gateway and the demo robot.\n", flush=True)

    stopping = []
    signal.signal(signal.SIGINT, lambda *_: stopping.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stopping.append(1))
    code = 0
    try:
        while not stopping and gateway.alive() and robot.alive():
            try:
                gateway.proc.wait(timeout=0.5)
            except subprocess.TimeoutExpired:
                pass
        if not gateway.alive():
            code = gateway.returncode
    finally:
        for child in (gateway, robot):
            child.send(signal.SIGTERM)
        for child in (gateway, robot):
            try:
                child.proc.wait(timeout=12)
            except subprocess.TimeoutExpired:
                child.kill_group()
                child.proc.wait(timeout=5)
    return code


if __name__ == "__main__":
    sys.exit(main())
