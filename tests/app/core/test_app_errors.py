"""app/core/errors.py's answer to each IPC error code, against the wire's code table (ipc/errors.py)."""

from __future__ import annotations

from app.core.errors import IPC_ANSWERS, ApiError
from ipc.errors import CODES, IpcError


def test_every_wire_code_has_exactly_one_http_answer():
    assert set(IPC_ANSWERS) == set(CODES)


def test_an_ipc_error_becomes_the_answer_of_its_code():
    api = ApiError.from_ipc(IpcError("cold-wait-cap-exceeded", "cap", {"cold_wait_cap": 4}), {"topic": "/x"})
    assert (api.status, api.error_code, api.vendor_code, api.retry_after) == \
        (503, "vendor-error", "x-medkit-cold-wait-cap-exceeded", 1)
    assert api.parameters == {"cold_wait_cap": 4, "topic": "/x"}


def test_an_unknown_code_from_the_wire_is_internal_and_no_http_status_travels():
    exc = IpcError.from_wire({"code": "made-up", "message": "m", "status": 200, "params": {}})
    assert exc.code == "internal" and ApiError.from_ipc(exc).status == 500
    assert "status" not in IpcError("backpressure", "busy").to_wire()
