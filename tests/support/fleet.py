"""The fleet's processes for tests (issue 34): a Zenoh router, robots' gateways, the fleet gateway.

- :class:`Router`: ``sovd-zenoh-router`` on a free loopback port (``ready <zid>`` once it listens).
- :class:`FleetGateway`: ``sovd-gateway --fleet-aggregate``; healthy once ``/health`` says its fleet
  link answers (it has no ROS worker to wait for).
- :class:`SimFleet`: ``bench/fleetsim.py``'s simulated robots, steered line by line.
- :func:`make_pki`: a CA and certificates signed by it (``cryptography``), for the TLS tests.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import requests

from .gateway import Gateway
from .procs import Proc, free_port

BIN = Path(sys.executable).parent
TOKEN = "fleet-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


class Router(Proc):
    """``sovd-zenoh-router`` on a free port; with ``config``, that file says where it listens (``port``)."""

    def __init__(self, config: str | None = None, port: int | None = None, scheme: str = "tcp",
                 host: str = "127.0.0.1"):
        self.port = port or free_port()
        self.endpoint = f"{scheme}/{host}:{self.port}"
        args = ["--config", config] if config else ["--listen", self.endpoint]
        super().__init__([str(BIN / "sovd-zenoh-router"), *args], name="zenoh router")
        self.wait_line(lambda line: line.startswith("ready "), 30)


class FleetGateway(Gateway):
    def _healthy(self) -> bool:
        if self.proc.poll() is not None:
            raise AssertionError(f"sovd-gateway exited with {self.proc.returncode}:\n" + self.tail(60))
        r = requests.get(self.api + "/health", timeout=2)
        return r.status_code == 200 and r.json()["x-medkit-fleet"]["link_alive"]

    def fleet_link(self):
        """The fleet-link process (the child that stands where a ROS worker would)."""
        for p in self._children():
            if any("fleetlink" in part for part in p.cmdline()):
                return p
        raise RuntimeError("no fleet link under the gateway")


class SimFleet(Proc):
    """Simulated robots (``bench/fleetsim.py``) on ``router``; ``answers`` as :func:`bench.fleetsim.record` makes."""

    def __init__(self, router: Router, answers: dict, robots: int, **spec):
        self.answers_file = tempfile.NamedTemporaryFile("w", suffix=".json", delete=False)  # noqa: SIM115
        json.dump(answers, self.answers_file)
        self.answers_file.close()
        full = {"connect": router.endpoint, "robots": robots, "answers": self.answers_file.name, **spec}
        super().__init__([sys.executable, "-m", "bench.fleetsim", json.dumps(full)], name="fleet simulator",
                         stdin=subprocess.PIPE)
        self.wait_line(lambda line: line == "READY", 60)

    def send(self, command: str, timeout: float = 10.0) -> None:
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()
        self.wait_line(lambda line: line in (f"OK {command}",) or line.startswith(f"ERROR {command}"), timeout)


def make_pki(directory: Path, names: dict[str, str], dns: str = "localhost") -> None:
    """``ca.pem``/``ca.key`` and, for each ``file stem -> common name``, ``<stem>.pem``/``<stem>.key``
    signed by that CA (EC P-256, a day long); each certificate also names ``dns`` (the router's)."""
    import datetime

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    now = datetime.datetime.now(datetime.UTC)

    def write(stem: str, key, cert) -> None:
        (directory / f"{stem}.key").write_bytes(key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()))
        (directory / f"{stem}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))

    def name(cn: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = (x509.CertificateBuilder().subject_name(name("sovd-fleet-ca")).issuer_name(name("sovd-fleet-ca"))
          .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
          .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=1))
          .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
          .sign(ca_key, hashes.SHA256()))
    write("ca", ca_key, ca)
    for stem, cn in names.items():
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (x509.CertificateBuilder().subject_name(name(cn)).issuer_name(ca.subject)
                .public_key(key.public_key()).serial_number(x509.random_serial_number())
                .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=1))
                .add_extension(x509.SubjectAlternativeName([x509.DNSName(dns)]), critical=False)
                .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                      ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
                .sign(ca_key, hashes.SHA256()))
        write(stem, key, cert)
