"""One queued command of the ROS thread (:class:`Task`), and one of its timers (:class:`Timer`).

Both are made by the executor (``executor.py``) and handed to the families: a command handler
answers its task once (:meth:`Task.reply` or :meth:`Task.fail`); a timer can be cancelled.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from ipc import protocol
from ipc.errors import IpcError
from ipc.server import Request

if TYPE_CHECKING:
    from .executor import RosExecutor


class Task:
    """One queued command; ``reply``/``fail`` may be called once, on the ROS thread.

    ``request_id`` is the HTTP request's id when the HTTP side sent one: log
    lines written while the task runs or is answered carry it (``requestlog.py``).
    """

    __slots__ = ("cmd", "args", "identity", "rid", "deadline", "received", "request_id", "answered",
                 "counted", "_executor")

    def __init__(self, executor: RosExecutor, request: Request, deadline: float, received: float):
        self.cmd = request.cmd
        self.args = request.args
        self.identity = request.identity
        self.rid = request.rid
        self.deadline = deadline
        self.received = received
        self.request_id = request.request_id
        self.answered = False
        self.counted = False  # in stats.commands: before its reply goes, so a later ``stats`` sees it
        self._executor = executor

    def reply(self, result: dict[str, Any]) -> None:
        if not self.answered:
            self.answered = True
            self._executor._send(self, {"v": protocol.VERSION, "id": self.rid, "ok": True, "result": result})

    def fail(self, error: IpcError) -> None:
        if not self.answered:
            self.answered = True
            self._executor._send(self, {"v": protocol.VERSION, "id": self.rid, "ok": False,
                                        "error": error.to_wire()})


class Timer:
    __slots__ = ("when", "fn", "cancelled")

    def __init__(self, when: float, fn: Callable[[], None]):
        self.when = when
        self.fn = fn
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True
