"""``make run``: the demo robot and the gateway in the foreground; Ctrl-C stops both."""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
from pathlib import Path

BIN = Path(sys.executable).parent


def main() -> int:
    parser = argparse.ArgumentParser(description="Run the demo robot and the gateway together.")
    parser.add_argument("--bind", default="127.0.0.1:8080")
    args, gateway_args = parser.parse_known_args()
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    robot = subprocess.Popen([sys.executable, "-m", "demo.robot"], env=env)
    # Publishing is off by default; the demo turns it on so that the README's PUT example works.
    gateway = subprocess.Popen([str(BIN / "sovd-gateway"), "--bind", args.bind, "--allow-publish",
                                *gateway_args], env=env)
    host, _, port = args.bind.rpartition(":")
    print(f"\nsovd-gateway demo: try  curl http://{host}:{port}/api/v1/health\n"
          "Ctrl-C stops the gateway and the demo robot.\n", flush=True)

    stopping = []
    signal.signal(signal.SIGINT, lambda *_: stopping.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stopping.append(1))
    code = 0
    try:
        while not stopping and gateway.poll() is None and robot.poll() is None:
            try:
                gateway.wait(timeout=0.5)
            except subprocess.TimeoutExpired:
                pass
        if gateway.poll() is not None:
            code = gateway.returncode
    finally:
        for proc in (gateway, robot):
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in (gateway, robot):
            try:
                proc.wait(timeout=12)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5)
    return code


if __name__ == "__main__":
    sys.exit(main())
