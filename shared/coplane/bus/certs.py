"""A local certificate authority and one key + certificate per bus identity (`coplane certs init`).

Layout of a certificates folder (what `BusSecurity.certs` points at)::

    ca.crt  ca.key                   the fleet's own CA (its key signs; keep it off the vehicles)
    router.crt  router.key           the Zenoh router's TLS server certificate
    fusion.crt  api.crt  monitor.crt the services' client certificates (and their .key files)
    fusion-<server id>.crt  ...      one per fusion server of a fleet with regions (`servers`)
    vehicle-<id>.crt  ...            one per vehicle

The certificate's common name is the identity: the router's access control (coplane.bus.acl)
grants rights by it. Every certificate carries the names a router may be reached by (localhost,
127.0.0.1, ::1 and the docker-compose service names), because Zenoh checks the router's name on
connect. Keys are ECDSA P-256 (fast to make, accepted by rustls), written 0600.

Idempotent: an existing CA is never replaced, an existing identity whose certificate the CA signed
is kept, and anything inconsistent (a certificate without its key, one signed by another CA) is an
error naming the file, never silently overwritten.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from coplane.bus.security import SERVICE_IDENTITIES, check_identity, server_identity, vehicle_identity
from coplane.errors import ConfigError

CA = "ca"
CA_DAYS = 3650
LEAF_DAYS = 825
# every name a client may use to reach the router: local runs and the docker-compose network
DNS_NAMES = ("localhost", "zenoh-router", "router")
IP_NAMES = ("127.0.0.1", "::1")


@dataclass
class CertsResult:
    """What `init_certs` did: identities it created and those already there (kept as they are)."""

    folder: Path
    ca_created: bool
    created: list[str] = field(default_factory=list)
    existing: list[str] = field(default_factory=list)


def cert_path(folder: Path, identity: str) -> Path:
    return folder / f"{identity}.crt"


def key_path(folder: Path, identity: str) -> Path:
    return folder / f"{identity}.key"


def identities_for(vehicles: Iterable[str], servers: Iterable[str] = ()) -> list[str]:
    """The router, the services, one identity per fusion server id and one per vehicle, in that order."""
    return [
        *SERVICE_IDENTITIES,
        *(server_identity(s) for s in servers),
        *(vehicle_identity(v) for v in vehicles),
    ]


def init_certs(
    folder: Path,
    vehicles: Sequence[str],
    extra_dns: Sequence[str] = (),
    owner: tuple[int, int] | None = None,
    servers: Sequence[str] = (),
) -> CertsResult:
    """Create (or complete) the certificates folder for these vehicles; see the module docstring.

    `extra_dns`: more names the router is reached by. `owner`: (uid, gid) to give the key files
    (the one-shot docker-compose service runs as root and hands them to the services' user).
    `servers`: the ids of a fleet's fusion servers with regions, each given its own identity.
    """
    folder.mkdir(parents=True, exist_ok=True)
    ca_key, ca_cert, ca_created = _load_or_make_ca(folder)
    result = CertsResult(folder, ca_created)
    dns = (*DNS_NAMES, *extra_dns)
    for identity in identities_for(vehicles, servers):
        check_identity(identity)
        crt, key = cert_path(folder, identity), key_path(folder, identity)
        if crt.exists() or key.exists():
            _check_existing(identity, crt, key, ca_cert)
            result.existing.append(identity)
            continue
        leaf_key = ec.generate_private_key(ec.SECP256R1())
        leaf = _leaf_certificate(identity, leaf_key, ca_key, ca_cert, dns)
        _write_key(key, leaf_key, owner)
        crt.write_bytes(leaf.public_bytes(serialization.Encoding.PEM))
        result.created.append(identity)
    return result


def common_name(cert: x509.Certificate) -> str:
    attrs = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(attrs[0].value) if attrs else ""


def load_cert(path: Path) -> x509.Certificate:
    try:
        return x509.load_pem_x509_certificate(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: not a readable PEM certificate ({exc})") from exc


# -- internals ------------------------------------------------------------------------------------


def _now() -> dt.datetime:
    return dt.datetime.now(dt.UTC)


def _write_key(path: Path, key: ec.EllipticCurvePrivateKey, owner: tuple[int, int] | None) -> None:
    """PKCS#8 PEM, created 0600 (never world-readable, not even for an instant)."""
    data = key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    if owner is not None:
        os.chown(path, *owner)


def _load_or_make_ca(folder: Path) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate, bool]:
    crt, key = cert_path(folder, CA), key_path(folder, CA)
    if crt.exists() and key.exists():
        ca_key = serialization.load_pem_private_key(key.read_bytes(), password=None)
        if not isinstance(ca_key, ec.EllipticCurvePrivateKey):
            raise ConfigError(f"{key}: not an EC private key; remove the folder's ca.* to make a new CA")
        cert = load_cert(crt)
        if cert.public_key() != ca_key.public_key():
            raise ConfigError(f"{crt} does not belong to {key}; refusing to touch an existing CA")
        return ca_key, cert, False
    if crt.exists() or key.exists():
        have = crt if crt.exists() else key
        raise ConfigError(f"{have} exists without its pair; refusing to replace an existing CA")
    ca_key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "coplane local CA")])
    now = _now()
    ski = x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key())
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=CA_DAYS))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=False,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=True,
                crl_sign=True,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(ski, critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    _write_key(key, ca_key, None)  # the CA key stays with whoever made it, never handed on
    crt.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return ca_key, cert, True


def _leaf_certificate(
    identity: str,
    key: ec.EllipticCurvePrivateKey,
    ca_key: ec.EllipticCurvePrivateKey,
    ca_cert: x509.Certificate,
    dns: Sequence[str],
) -> x509.Certificate:
    now = _now()
    names: list[x509.GeneralName] = [x509.DNSName(n) for n in dict.fromkeys(dns)]
    names += [x509.IPAddress(ipaddress.ip_address(ip)) for ip in IP_NAMES]
    ca_ski = ca_cert.extensions.get_extension_for_class(x509.SubjectKeyIdentifier).value
    return (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, identity)]))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=LEAF_DAYS))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=False,
                crl_sign=False,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(
            x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
            critical=False,
        )
        .add_extension(x509.SubjectAlternativeName(names), critical=False)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_subject_key_identifier(ca_ski), critical=False)
        .sign(ca_key, hashes.SHA256())
    )


def _check_existing(identity: str, crt: Path, key: Path, ca_cert: x509.Certificate) -> None:
    """An identity already on disk must be complete, named right and signed by this CA."""
    if not (crt.exists() and key.exists()):
        missing = key if crt.exists() else crt
        raise ConfigError(f"{missing} is missing but its pair exists; remove the other file to remake it")
    cert = load_cert(crt)
    if common_name(cert) != identity:
        raise ConfigError(f"{crt}: common name {common_name(cert)!r}, expected {identity!r}")
    try:
        cert.verify_directly_issued_by(ca_cert)
    except (InvalidSignature, TypeError, ValueError) as exc:
        raise ConfigError(f"{crt} was not signed by this folder's ca.crt; remove it to remake it") from exc
