"""`coplane certs init`: a CA and one certificate per identity, private keys 0600, never overwritten."""

from __future__ import annotations

import ipaddress
import stat
from pathlib import Path

import pytest
from cryptography import x509
from typer.testing import CliRunner

from coplane.bus import BusSecurity, session_config
from coplane.bus.certs import common_name, init_certs, load_cert
from coplane.bus.config import vehicles_in
from coplane.cli import app
from coplane.errors import ConfigError


def test_identities_names_and_permissions(tmp_path: Path) -> None:
    r = init_certs(tmp_path, ["u1", "u2"])
    assert r.ca_created and r.existing == []
    assert r.created == ["router", "fusion", "api", "monitor", "vehicle-u1", "vehicle-u2"]
    ca = load_cert(tmp_path / "ca.crt")
    for identity in r.created:
        cert = load_cert(tmp_path / f"{identity}.crt")
        assert common_name(cert) == identity
        cert.verify_directly_issued_by(ca)
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        assert {"localhost", "zenoh-router"} <= set(san.get_values_for_type(x509.DNSName))
        assert ipaddress.ip_address("127.0.0.1") in san.get_values_for_type(x509.IPAddress)
    for key in tmp_path.glob("*.key"):
        assert stat.S_IMODE(key.stat().st_mode) == 0o600, key
    assert vehicles_in(tmp_path) == ["u1", "u2"]


def test_idempotent_and_never_overwrites(tmp_path: Path) -> None:
    init_certs(tmp_path, ["u1"])
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    again = init_certs(tmp_path, ["u1", "u2"])
    assert not again.ca_created and again.created == ["vehicle-u2"]
    assert "vehicle-u1" in again.existing
    assert all((tmp_path / n).read_bytes() == b for n, b in before.items())
    # a certificate from another CA is named, not replaced
    other = tmp_path / "other"
    init_certs(other, ["u3"])
    (tmp_path / "vehicle-u3.crt").write_bytes((other / "vehicle-u3.crt").read_bytes())
    (tmp_path / "vehicle-u3.key").write_bytes((other / "vehicle-u3.key").read_bytes())
    with pytest.raises(ConfigError, match=r"vehicle-u3\.crt was not signed"):
        init_certs(tmp_path, ["u3"])
    (tmp_path / "ca.key").unlink()
    with pytest.raises(ConfigError, match="refusing to replace an existing CA"):
        init_certs(tmp_path, ["u1"])


def test_cli_and_secure_session_config(tmp_path: Path) -> None:
    out = CliRunner().invoke(app, ["certs", "init", str(tmp_path / "c"), "--vehicles", "u1,u2"])
    assert out.exit_code == 0, out.output
    assert "made a new CA" in " ".join(out.output.split())
    again = CliRunner().invoke(app, ["certs", "init", str(tmp_path / "c"), "--vehicles", "u1"])
    text = " ".join(again.output.split())  # rich wraps long lines
    assert again.exit_code == 0 and "kept the existing CA" in text and "vehicle-u1" in text
    sec = BusSecurity(certs=tmp_path / "c", identity="vehicle-u1")
    cfg = session_config("client", ["tcp/127.0.0.1:7447"], security=sec)
    assert cfg.get_json("connect/endpoints") == '["tls/127.0.0.1:7447"]'  # upgraded to TLS
    assert "vehicle-u1.key" in cfg.get_json("transport/link/tls/connect_private_key")
    with pytest.raises(ConfigError, match="not found"):
        session_config("client", ["tcp/x:1"], security=sec.as_identity("vehicle-u9"))
    with pytest.raises(ConfigError, match="needs certificates"):
        session_config("client", ["tls/x:1"], security=BusSecurity(insecure=True))


def test_security_from_the_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    init_certs(tmp_path, ["u1"])
    monkeypatch.setenv("COPLANE_BUS_CERTS", str(tmp_path))
    monkeypatch.setenv("COPLANE_BUS_IDENTITY", "fusion")
    cfg = session_config("client", ["tcp/127.0.0.1:7447"])
    assert "fusion.crt" in cfg.get_json("transport/link/tls/connect_certificate")
    monkeypatch.setenv("COPLANE_BUS_INSECURE", "1")
    assert (
        session_config("client", ["tcp/127.0.0.1:7447"]).get_json("connect/endpoints")
        == '["tcp/127.0.0.1:7447"]'
    )
