"""The layout the brief fixes: the ROS worker and the shared IPC layer import nothing from ``app/``.

The HTTP side may change (Flask, gunicorn, gevent) without touching the process that owns rclpy.
"""

import subprocess
import sys

CHECK = r"""
import importlib, pkgutil, sys
import ipc, rosworker
for pkg in (ipc, rosworker):
    for mod in pkgutil.iter_modules(pkg.__path__):
        importlib.import_module(f"{pkg.__name__}.{mod.name}")
loaded = sorted(m for m in sys.modules if m == "app" or m.startswith("app."))
print(",".join(loaded))
"""


def test_rosworker_and_ipc_import_nothing_from_app():
    out = subprocess.run([sys.executable, "-c", CHECK], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"modules of app/ imported by rosworker/ or ipc/: {out.stdout.strip()}"
