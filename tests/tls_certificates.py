"""Certificates for the Zenoh TLS and access-control tests: a CA, the controller's, and one per client.

Written as the shipped example files expect them (controller/configs/zenoh/: ``ca.pem``,
``controller.pem`` and ``controller-key.pem``, ``<name>.pem`` and ``<name>-key.pem`` per client,
whose certificate's common name is ``cheope-<name>``). ``other_ca`` signs a client that the
controller's CA does not know.
"""

from __future__ import annotations

import datetime
import ipaddress
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

_DAY = datetime.timedelta(days=1)


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _write_key(key: ec.EllipticCurvePrivateKey, path: Path) -> None:
    path.write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )
    )


class CertificateAuthority:
    def __init__(self, common_name: str) -> None:
        self.key = ec.generate_private_key(ec.SECP256R1())
        now = datetime.datetime.now(datetime.UTC)
        self.name = _name(common_name)
        self.cert = (
            x509.CertificateBuilder()
            .subject_name(self.name)
            .issuer_name(self.name)
            .public_key(self.key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - _DAY)
            .not_valid_after(now + 30 * _DAY)
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .add_extension(
                x509.KeyUsage(True, False, False, False, False, True, True, False, False), critical=True
            )
            .sign(self.key, hashes.SHA256())
        )

    def write(self, path: Path) -> None:
        path.write_bytes(self.cert.public_bytes(serialization.Encoding.PEM))

    def issue(self, common_name: str, cert_path: Path, key_path: Path, server: bool) -> None:
        """A certificate for ``common_name``; a server's names localhost and 127.0.0.1 as well."""
        key = ec.generate_private_key(ec.SECP256R1())
        now = datetime.datetime.now(datetime.UTC)
        usage = ExtendedKeyUsageOID.SERVER_AUTH if server else ExtendedKeyUsageOID.CLIENT_AUTH
        names: list[x509.GeneralName] = [x509.DNSName(common_name)]
        if server:
            names += [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]
        cert = (
            x509.CertificateBuilder()
            .subject_name(_name(common_name))
            .issuer_name(self.name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - _DAY)
            .not_valid_after(now + 30 * _DAY)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName(names), critical=False)
            .add_extension(x509.ExtendedKeyUsage([usage]), critical=False)
            .sign(self.key, hashes.SHA256())
        )
        cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        _write_key(key, key_path)


def write_certificates(directory: Path, clients: tuple[str, ...] = ("viewer", "operator")) -> None:
    """``ca.pem``, the controller's pair and each client's (common name ``cheope-<client>``), plus
    ``stranger.pem``/``stranger-key.pem`` (common name ``cheope-operator``) from another CA."""
    directory.mkdir(parents=True, exist_ok=True)
    ca = CertificateAuthority("cheope test CA")
    ca.write(directory / "ca.pem")
    ca.issue("cheope-controller", directory / "controller.pem", directory / "controller-key.pem", server=True)
    for name in clients:
        ca.issue(f"cheope-{name}", directory / f"{name}.pem", directory / f"{name}-key.pem", server=False)
    CertificateAuthority("another CA").issue(
        "cheope-operator", directory / "stranger.pem", directory / "stranger-key.pem", server=False
    )
