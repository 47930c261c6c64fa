"""TLS directly on the gateway (gunicorn's certfile and keyfile), with a certificate made here: HTTPS
answers, a plain-HTTP client gets nothing, and nothing older than TLS 1.2 (or 1.3 when asked) is spoken.
"""

from __future__ import annotations

import datetime
import http.client
import ipaddress
import socket
import ssl
import warnings

import pytest
import requests

from common.harness.gateway import Gateway


def certificate(directory) -> tuple[str, str]:
    """A self-signed certificate for 127.0.0.1 (and its key), as PEM files."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "sovd-gateway test")])
    now = datetime.datetime.now(datetime.UTC)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=1))
            .not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
                           critical=False)
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .sign(key, hashes.SHA256()))
    cert_path, key_path = directory / "gateway.crt", directory / "gateway.key"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))
    key_path.chmod(0o600)
    return str(cert_path), str(key_path)


def speaks(port: int, cafile: str, version: ssl.TLSVersion) -> bool:
    """Whether a client that speaks at most ``version`` gets an answer."""
    context = ssl.create_default_context(cafile=cafile)
    with warnings.catch_warnings():  # TLS 1.0 and 1.1 are deprecated: that is the point
        warnings.simplefilter("ignore", DeprecationWarning)
        context.minimum_version = ssl.TLSVersion.MINIMUM_SUPPORTED
        context.maximum_version = version
    try:
        context.set_ciphers("DEFAULT:@SECLEVEL=0")  # let the client offer what it can; the server decides
    except ssl.SSLError:
        pass
    conn = http.client.HTTPSConnection("127.0.0.1", port, timeout=10, context=context)
    try:
        conn.request("GET", "/api/v1/health")
        return conn.getresponse().status == 200
    except (ssl.SSLError, ConnectionError, OSError):
        return False
    finally:
        conn.close()


@pytest.fixture(scope="module")
def cert(tmp_path_factory):
    return certificate(tmp_path_factory.mktemp("tls"))


def test_https_answers_and_plain_http_gets_nothing(cert):
    cert_path, key_path = cert
    gw = Gateway("--tls-cert", cert_path, "--tls-key", key_path)
    try:
        assert gw.url.startswith("https://")
        r = gw.get("/")  # the certificate checked against the file (common/harness/gateway.py)
        assert r.status_code == 200
        assert r.json()["tls"] == {"enabled": True, "min_version": "1.2"} and r.json()["capabilities"]["tls"] is True
        with pytest.raises(requests.exceptions.ConnectionError):
            requests.get(f"http://127.0.0.1:{gw.port}/api/v1/health", timeout=10)
        with socket.create_connection(("127.0.0.1", gw.port), timeout=10) as raw:  # no answer in clear text
            raw.sendall(b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\n\r\n")
            try:
                answer = raw.recv(4096)   # a TLS alert at most, or the connection closed
            except ConnectionResetError:
                answer = b""
        assert b"HTTP/1.1" not in answer and b"healthy" not in answer
        assert speaks(gw.port, cert_path, ssl.TLSVersion.TLSv1_3)
        assert speaks(gw.port, cert_path, ssl.TLSVersion.TLSv1_2)
        assert not speaks(gw.port, cert_path, ssl.TLSVersion.TLSv1_1)
        assert not speaks(gw.port, cert_path, ssl.TLSVersion.TLSv1)
        assert gw.get("/health").json()["status"] == "healthy"  # the gateway is unharmed by all of it
    finally:
        gw.stop()


def test_tls_1_3_only_when_asked(cert):
    cert_path, key_path = cert
    gw = Gateway("--tls-cert", cert_path, "--tls-key", key_path, "--tls-min-version", "1.3", "--workers", "1")
    try:
        assert gw.get("/").json()["tls"]["min_version"] == "1.3"
        assert speaks(gw.port, cert_path, ssl.TLSVersion.TLSv1_3)
        assert not speaks(gw.port, cert_path, ssl.TLSVersion.TLSv1_2)
    finally:
        gw.stop()
