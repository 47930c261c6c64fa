"""Session-wide isolation: each test session gets its own ROS domain, localhost only.

This runs before any test module imports rclpy, so every process the tests
start (they inherit the environment) lives in the same private domain.
"""

from __future__ import annotations

import fcntl
import os
import random

import pytest


def _claim_domain() -> int:
    """Pick a ROS_DOMAIN_ID no other test session on this machine holds (flock per id)."""
    lock_dir = "/tmp/sovd-gateway-test-domains"
    os.makedirs(lock_dir, exist_ok=True)
    candidates = list(range(1, 101))
    random.shuffle(candidates)
    for domain in candidates:
        fh = open(os.path.join(lock_dir, f"{domain}.lock"), "w")
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.close()
            continue
        globals()["_DOMAIN_LOCK"] = fh  # held for the whole session
        return domain
    raise RuntimeError("no free ROS_DOMAIN_ID in 1..100 for this test session")


if "SOVD_TEST_DOMAIN_CLAIMED" not in os.environ:
    os.environ["ROS_DOMAIN_ID"] = str(_claim_domain())
    os.environ["SOVD_TEST_DOMAIN_CLAIMED"] = "1"
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_STATIC_PEERS", None)
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
os.environ["PYTHONUNBUFFERED"] = "1"


@pytest.fixture(scope="session")
def ros_domain() -> int:
    return int(os.environ["ROS_DOMAIN_ID"])
