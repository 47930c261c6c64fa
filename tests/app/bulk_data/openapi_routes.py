"""The bulk-data routes (app/bulk_data/spec.py, issue 32) answer per the OpenAPI document: every route and its
statuses, a recording on disk as the ROS worker lists it (the real recordings:
tests/system/bulk_data/test_bulk_data.py); run by tests/app/openapi/test_app_openapi.py."""

from __future__ import annotations

import io
import os
import tempfile

from ipc.errors import IpcError
from tests.app.openapi.answers import AUTH, ENTITY, TOKEN
from tests.support.fakeworker import make_app


def exercise(ex) -> None:
    fw, auth = ex.fw, AUTH
    with tempfile.TemporaryDirectory() as tmp:
        bag = os.path.join(tmp, "fault_HOT_1.mcap")
        with open(bag, "wb") as fh:
            fh.write(b"\x89MCAP0\r\n" + bytes(range(256)))
        recording = {"id": "fault_HOT_1", "format": "mcap", "fault_codes": ["HOT"],
                     "sources": {"HOT": ["/powertrain/engine/temp_sensor"]}, "created_ns": 1_700_000_000_000_000_000,
                     "started_ns": 1, "ended_ns": 2, "duration_sec": 1.5, "messages": 3, "path": bag, "size": 264,
                     "topics": [{"topic": "/powertrain/engine/temperature", "type": "sensor_msgs/msg/Temperature"}]}
        fw.replies = {**getattr(fw, "replies", {}), "bulk_rosbags": {"items": [recording]},
                      "bulk_rosbag_get": lambda args: recording if args["id"] == "fault_HOT_1" else
                      IpcError("no-such-recording", "Bulk-data not found", {"bulk_data_id": args["id"]}),
                      "fault_list": {"items": []}}
        client = make_app(fw, allow_bulk_data=True, api_token=TOKEN, bulk_data_categories="calibration",
                          bulk_data_storage_dir=os.path.join(tmp, "files"), bulk_data_max_upload_size=1000,
                          bulk_data_max_total_mb=1).test_client()
        off = make_app(fw, bulk_data_categories="calibration", bulk_data_storage_dir=os.path.join(tmp, "files"),
                       ).test_client()
        upload = {"data": {"file": (io.BytesIO(b"calibrated"), "cal.bin")}, "content_type": "multipart/form-data"}
        made = client.post("/api/v1/apps/temp_sensor/bulk-data/calibration", headers=auth,
                           **{**upload, "data": {"file": (io.BytesIO(b"calibrated"), "cal.bin")}})
        assert made.status_code == 201, made.data
        for collection, eid in ENTITY.items():
            base = f"/api/v1/{collection}/{eid or 'nope'}/bulk-data"
            requests = [("GET", base, {}), ("GET", f"/api/v1/{collection}/bad.id/bulk-data", {}),
                        ("GET", base + "/rosbags", {}), ("GET", base + "/nope", {}), ("GET", base + "/..%2Fx", {}),
                        ("GET", base + "/rosbags/fault_HOT_1", {}),
                        ("GET", base + "/rosbags/fault_HOT_1", {"headers": {"Range": "bytes=0-9"}}),
                        ("GET", base + "/rosbags/fault_HOT_1", {"headers": {"Range": "bytes=999-"}}),
                        ("GET", base + "/rosbags/fault_NONE_1", {}), ("GET", base + "/rosbags/..%2F..%2Fx", {}),
                        ("GET", base + "/calibration", {}), ("GET", base + "/calibration/nope_1", {})]
            if collection in ("areas", "components"):
                sub = f"{base[:-len('/bulk-data')]}/{'subareas' if collection == 'areas' else 'subcomponents'}/s"
                requests += [("GET", sub + "/bulk-data", {}), ("GET", sub + "/bulk-data/rosbags", {}),
                             ("GET", sub + "/bulk-data/rosbags/fault_HOT_1", {})]
            if collection in ("apps", "components"):
                item = f"{base}/calibration/{made.get_json()['id']}" if collection == "apps" else base + "/calibration/x_1"
                requests += [("GET", item, {}),
                             ("POST", base + "/calibration", {**upload, "headers": auth}),
                             ("POST", base + "/calibration", {**upload}),
                             ("POST", base + "/calibration", {**upload, "headers": {"Authorization": "Bearer no"}}),
                             ("POST", base + "/rosbags", {**upload, "headers": auth}),
                             ("POST", base + "/nope", {**upload, "headers": auth}),
                             ("POST", base + "/calibration", {"data": b"x", "content_type": "text/plain",
                                                              "headers": auth}),
                             ("POST", base + "/calibration", {"data": {"file": (io.BytesIO(b"x" * 2000), "big")},
                                                              "content_type": "multipart/form-data", "headers": auth}),
                             ("DELETE", item, {"headers": auth}), ("DELETE", item, {"headers": auth}),
                             ("DELETE", item, {}), ("DELETE", base + "/rosbags/fault_HOT_1", {"headers": auth})]
            for method, path, kw in requests:
                if "data" in kw and isinstance(kw["data"], dict):  # a fresh file object per request
                    kw = {**kw, "data": {k: (io.BytesIO(v[0].getvalue()), v[1]) for k, v in kw["data"].items()}}
                ex.answer(method, path, client, **kw)
            r = off.post(base + "/calibration", **{**upload, "data": {"file": (io.BytesIO(b"x"), "x")}})
            assert collection not in ("apps", "components") or r.status_code == 403, r.data
        del fw.replies["bulk_rosbags"], fw.replies["bulk_rosbag_get"], fw.replies["fault_list"]
    for statuses in (ex.seen["GET /apps/{app_id}/bulk-data/{category_id}/{file_id}"],
                     ex.seen["POST /apps/{app_id}/bulk-data/{category_id}"]):
        assert len(statuses) >= 3, statuses
