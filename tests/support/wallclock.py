"""Step the wall clock of a test gateway's processes: ``WallClock`` writes what ``wallstep/sitecustomize.py`` reads.

    clock = WallClock()
    gw = Gateway(env=clock.env())
    clock.step(-3600)        # every process of that gateway now reads an hour earlier
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

SITE = Path(__file__).parent / "wallstep"


class WallClock:
    def __init__(self):
        fd, self.path = tempfile.mkstemp(prefix="sovd-wall-step-")
        os.close(fd)
        self.offset_ns = 0
        self._write()

    def env(self) -> dict[str, str]:
        """The environment that makes a process (and its children) read this clock."""
        return {"PYTHONPATH": os.pathsep.join(filter(None, [str(SITE), os.environ.get("PYTHONPATH")])),
                "SOVD_TEST_WALL_STEP_FILE": self.path}

    def step(self, seconds: float) -> None:
        """Step the clock by ``seconds`` (negative: backwards) from where it is now."""
        self.offset_ns += int(seconds * 1e9)
        self._write()

    def _write(self) -> None:
        with open(self.path + ".new", "w") as fh:
            fh.write(str(self.offset_ns))
        os.replace(self.path + ".new", self.path)  # a reader sees the old step or the new one

    def close(self) -> None:
        for path in (self.path, self.path + ".new"):
            try:
                os.unlink(path)
            except OSError:
                pass
