"""Reading the gateway's ``/metrics`` in tests: families by name, one sample's value."""

from __future__ import annotations

import requests
from prometheus_client.parser import text_string_to_metric_families


def parse(text: str) -> dict:
    """A Prometheus text exposition: family name → family."""
    return {f.name: f for f in text_string_to_metric_families(text)}


def families(url: str, timeout: float = 10, **kw) -> dict:
    """``GET {url}/metrics`` parsed (asserts a 200)."""
    r = requests.get(url + "/metrics", timeout=timeout, **kw)
    assert r.status_code == 200, r.text[:300]
    return parse(r.text)


def value(families: dict, family: str, sample: str | None = None, **labels) -> float:
    """The value of the sample of ``family`` with these labels (0 when there is none)."""
    for s in families[family].samples if family in families else ():
        if s.name == (sample or family) and all(s.labels.get(k) == v for k, v in labels.items()):
            return s.value
    return 0.0
