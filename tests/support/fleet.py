"""The fleet for tests (issue 34): the token, the processes, certificates.

The processes are the harness's, shared with the bench (``common/harness/fleetsim.py``'s :class:`Router`
and :class:`SimFleet`, ``common/harness/gateway.py``'s :class:`FleetGateway`):

- :class:`Router`: ``sovd-zenoh-router`` on a free loopback port (``ready <zid>`` once it listens).
- :class:`FleetGateway`: ``sovd-gateway --fleet-aggregate``; healthy once ``/health`` says its fleet
  link answers (it has no ROS worker to wait for).
- :class:`SimFleet`: ``common/harness/fleetsim.py``'s simulated robots, steered line by line.
- :func:`make_pki`: a CA and certificates signed by it (``cryptography``), for the TLS tests.
"""

from __future__ import annotations

from pathlib import Path

from common.harness.fleetsim import Router, SimFleet
from common.harness.gateway import FleetGateway

__all__ = ["AUTH", "TOKEN", "FleetGateway", "Router", "SimFleet", "make_pki"]

TOKEN = "fleet-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


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
