"""The HTTP side imports no rclpy, and importing it does nothing process-wide."""

from __future__ import annotations

import subprocess
import sys

from common.harness.procs import REPO

HTTP_MODULES = ("app.wsgi", "app.core.errors", "app.core.rosclient", "app.core.entities", "app.openapi",
                "app.core.common", "app.core.root", "app.core.discovery", "app.data.routes",
                "app.data.checks", "app.core.auth", "ipc.client", "ipc.errors", "ipc.topics")


def run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)


def test_http_side_does_not_import_rclpy():
    code = ("import sys\n"
            + "".join(f"import {m}\n" for m in HTTP_MODULES)
            + "from app.wsgi import create_app\n"
            + "app = create_app({'runtime_dir': '/nonexistent-sovd-test'})\n"
            + "app.test_client().get('/api/v1/health')\n"
            + "bad = sorted(m for m in sys.modules if m == 'rclpy' or m.startswith(('rclpy.', 'rosworker')))\n"
            + "assert not bad, bad\n")
    result = run(code)
    assert result.returncode == 0, result.stderr


def test_import_makes_no_zmq_context_and_no_app():
    code = ("import zmq, gc\n"
            "import app.wsgi, app.data.routes, app.core.rosclient\n"
            "assert not [o for o in gc.get_objects() if isinstance(o, zmq.Context)]\n"
            "import flask\n"
            "assert not [o for o in gc.get_objects() if isinstance(o, flask.Flask)]\n")
    result = run(code)
    assert result.returncode == 0, result.stderr
