"""Who the client is: the TCP peer, or, behind a trusted proxy, the address that proxy forwarded.

gunicorn sets ``REMOTE_ADDR`` to the TCP peer, which behind nginx is nginx.
``forwarded_allow_ips`` (the setting gunicorn itself trusts ``X-Forwarded-Proto``
from) names the proxies whose ``X-Forwarded-For`` is believed.  Only then is
the header read, from the right: each address a trusted proxy appended is
skipped, and the first one that is not a trusted proxy is the client (what the
outermost trusted proxy saw).  A client cannot choose its own address by
sending the header: nginx appends the address it saw, and whatever the client
wrote stands to the left of it.  An entry that is not an IP address ends the
walk at the last good one.

Before each request (:func:`_resolve`, registered by the app factory after the
request id) the client's address replaces ``REMOTE_ADDR`` (the TCP peer is
kept as ``sovd.peer_addr``), so the rate limiter's buckets and the access
log's ``%(h)s`` are per real client.
"""

from __future__ import annotations

import functools
import ipaddress

from flask import Flask, current_app, request

EXTENSION = "sovd_clientaddr"
PEER_KEY = "sovd.peer_addr"
MAX_HOPS = 16  # X-Forwarded-For entries looked at, from the right


class Trusted:
    """The proxies of ``forwarded_allow_ips``: addresses or networks, or ``*`` for every peer."""

    def __init__(self, spec: str):
        items = [item.strip() for item in spec.split(",") if item.strip()]
        self.everyone = "*" in items
        self.networks = []
        for item in items:
            if item == "*":
                continue
            try:
                self.networks.append(ipaddress.ip_network(item, strict=False))
            except ValueError:
                continue  # gunicorn refuses what it cannot read; nothing to trust here either
        self.contains = functools.lru_cache(maxsize=1024)(self._contains)

    def _contains(self, address: str) -> bool:
        if self.everyone:
            return True
        ip = _ip(address)
        if ip is None:
            return False
        if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
            ip = ip.ipv4_mapped
        return any(ip in net for net in self.networks)


def _ip(text: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    try:
        return ipaddress.ip_address(text.strip().strip("[]"))
    except ValueError:
        return None


def client_address(peer: str, forwarded_for: str | None, trusted: Trusted) -> str:
    """The client behind ``peer``: see the module docstring."""
    if not forwarded_for or not trusted.contains(peer):
        return peer
    client = peer
    for hop in reversed(forwarded_for.split(",")[-MAX_HOPS:]):
        ip = _ip(hop)
        if ip is None:
            break
        client = str(ip)
        if not trusted.contains(client):
            break
    return client


def _resolve() -> None:
    environ = request.environ
    peer = environ.get("REMOTE_ADDR") or ""
    environ[PEER_KEY] = peer
    environ["REMOTE_ADDR"] = client_address(peer, environ.get("HTTP_X_FORWARDED_FOR"),
                                            current_app.extensions[EXTENSION])


def init_app(app: Flask) -> None:
    app.extensions[EXTENSION] = Trusted(app.config["SOVD"].forwarded_allow_ips)
    app.before_request(_resolve)
