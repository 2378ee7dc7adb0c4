"""Loopback certificates for Zenoh TLS links (``radical keys init``), made with ``cryptography``.

One self-signed certificate authority (EC P-256), one server certificate for the enforcement point
(the node or a router: subject alternative names ``IP:127.0.0.1`` and ``DNS:localhost``, since
Zenoh checks the name of the endpoint it connects to) and one client certificate per user whose
common name is the user name (Zenoh's ACL can name subjects by ``cert_common_names``). Everything
is written as PEM; private keys with mode 0600.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
from dataclasses import dataclass
from pathlib import Path

#: validity of every certificate made here (days)
VALID_DAYS = 825


@dataclass(frozen=True)
class Issued:
    """Paths of one issued certificate and its private key (PEM)."""

    cert: Path
    key: Path


def _private_key():
    from cryptography.hazmat.primitives.asymmetric import ec

    return ec.generate_private_key(ec.SECP256R1())


def _write_key(key, path: Path) -> None:
    from cryptography.hazmat.primitives import serialization

    data = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _write_cert(cert, path: Path) -> None:
    from cryptography.hazmat.primitives import serialization

    path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))


def _name(common_name: str):
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "RADICAL-RT"),
                      x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _builder(subject: str, issuer: str, public_key, now: dt.datetime):
    from cryptography import x509

    return (x509.CertificateBuilder().subject_name(_name(subject)).issuer_name(_name(issuer))
            .public_key(public_key).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=VALID_DAYS)))


def make_ca(directory: Path, common_name: str = "radical-rt loopback CA") -> Issued:
    """A self-signed CA in ``directory/ca.pem`` and ``directory/ca.key``."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes

    key = _private_key()
    now = dt.datetime.now(dt.UTC)
    cert = (_builder(common_name, common_name, key.public_key(), now)
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                         content_commitment=False, key_encipherment=False,
                                         data_encipherment=False, key_agreement=False,
                                         encipher_only=False, decipher_only=False), critical=True)
            .sign(key, hashes.SHA256()))
    out = Issued(directory / "ca.pem", directory / "ca.key")
    _write_cert(cert, out.cert)
    _write_key(key, out.key)
    return out


def issue(ca: Issued, directory: Path, stem: str, common_name: str, server: bool) -> Issued:
    """A certificate signed by ``ca``: ``directory/<stem>.pem`` and ``<stem>.key``.

    server: loopback subject alternative names and the server-auth usage; otherwise client-auth.
    """
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.x509.oid import ExtendedKeyUsageOID

    ca_key = serialization.load_pem_private_key(ca.key.read_bytes(), password=None)
    ca_cert = x509.load_pem_x509_certificate(ca.cert.read_bytes())
    key = _private_key()
    now = dt.datetime.now(dt.UTC)
    issuer = ca_cert.subject.get_attributes_for_oid(x509.oid.NameOID.COMMON_NAME)[0].value
    usage = ExtendedKeyUsageOID.SERVER_AUTH if server else ExtendedKeyUsageOID.CLIENT_AUTH
    b = (_builder(common_name, str(issuer), key.public_key(), now)
         .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
         .add_extension(x509.ExtendedKeyUsage([usage]), critical=False))
    if server:
        b = b.add_extension(x509.SubjectAlternativeName([
            x509.IPAddress(ipaddress.ip_address("127.0.0.1")), x509.DNSName("localhost")]),
            critical=False)
    cert = b.sign(ca_key, hashes.SHA256())
    out = Issued(directory / f"{stem}.pem", directory / f"{stem}.key")
    _write_cert(cert, out.cert)
    _write_key(key, out.key)
    return out


def common_name(cert_path: Path) -> str:
    """The subject common name of a PEM certificate."""
    from cryptography import x509

    cert = x509.load_pem_x509_certificate(Path(cert_path).read_bytes())
    return str(cert.subject.get_attributes_for_oid(x509.oid.NameOID.COMMON_NAME)[0].value)
