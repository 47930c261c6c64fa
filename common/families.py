"""Finding a process's resource families: every sub-package of a package that holds a ``FAMILY``.

The HTTP workers (``app/core/family.py``) and the ROS worker (``rosworker/core/family.py``) each
plug their families in the same way: a family is a folder with a ``FAMILY`` in its ``__init__.py``,
found here, never named by the code that loads it.
"""

from __future__ import annotations

import importlib
import pkgutil
from typing import Any


def discover(package: str, kind: type, shared: tuple[str, ...]) -> tuple[Any, ...]:
    """The ``FAMILY`` (an instance of ``kind``) of every sub-package of ``package`` but ``shared``
    (its core and the like), in name order."""
    root = importlib.import_module(package)
    found = []
    for info in sorted(pkgutil.iter_modules(root.__path__), key=lambda i: i.name):
        if not info.ispkg or info.name in shared:
            continue
        family = getattr(importlib.import_module(f"{package}.{info.name}"), "FAMILY", None)
        if isinstance(family, kind):
            found.append(family)
    return tuple(found)
