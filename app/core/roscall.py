"""One call to the ROS worker from a route, its error answered as the contract's (``errors.py``).

    answer = ros_call("trig_get", {"collection": c, "entity_id": e, "id": trigger_id},
                      not_found={"no-such-trigger": ("Trigger not found", {"trigger_id": trigger_id})})

- ``params`` go into the error's parameters (the entity, the resource asked for);
- ``not_found``: the codes that mean "this resource is not there", each with the
  404's message and parameters (``resource-not-found``);
- ``write``: the command changes something, so a deadline that passes leaves its
  outcome unknown: 504 ``not-responding`` saying so (a client must look before it
  tries again).

Every other error is :meth:`ApiError.from_ipc` (the one table, ``IPC_ANSWERS``).
"""

from __future__ import annotations

from typing import Any

from ipc.errors import IpcError

from . import rosclient
from .errors import ApiError

UNKNOWN_OUTCOME = "The ROS worker did not answer in time; the outcome is unknown"


def ros_call(cmd: str, args: dict[str, Any] | None = None, timeout: float | None = None, *,
             params: dict[str, Any] | None = None,
             not_found: dict[str, tuple[str, dict[str, Any]]] | None = None, write: bool = False) -> dict[str, Any]:
    """``cmd`` with ``args`` on the ROS worker (deadline ``timeout``, else ``ipc_timeout``): its answer, or
    the :class:`ApiError` a client gets for its error (see the module's docstring)."""
    try:
        return rosclient.get().call(cmd, args, timeout)
    except IpcError as exc:
        raise answer(exc, params, not_found, write) from None


def answer(exc: IpcError, params: dict[str, Any] | None = None,
           not_found: dict[str, tuple[str, dict[str, Any]]] | None = None, write: bool = False) -> ApiError:
    """The :class:`ApiError` a client gets for ``exc`` (see :func:`ros_call`)."""
    if not_found and exc.code in not_found:
        message, missing = not_found[exc.code]
        return ApiError(404, "resource-not-found", message, missing)
    if write and exc.code == "deadline-exceeded":
        return ApiError(504, "not-responding", UNKNOWN_OUTCOME, params)
    return ApiError.from_ipc(exc, params)
