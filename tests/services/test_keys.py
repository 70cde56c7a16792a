"""skynet keys: the development PKI is complete, private keys are private, CN = role, chain to the CA."""

from __future__ import annotations

import stat

import pytest
from cryptography import x509
from cryptography.x509.oid import NameOID

from protocol.keyset import KeySet
from protocol.signing import key_id, load_public
from services import keys as pki
from services.orchestration.trustmode import dev_keys, resolve


def test_init_writes_every_role_with_cn_and_private_modes(tmp_path):
    root = pki.init(tmp_path / "k", uavs=2)
    ca = x509.load_pem_x509_certificate((root / "ca.pem").read_bytes())
    for role in ("gateway", "gcs", "planner", "detector", "uav1", "uav2"):
        cert = x509.load_pem_x509_certificate((root / role / "tls.pem").read_bytes())
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == role
        cert.verify_directly_issued_by(ca)
        for private in ("tls.key", "sign.key"):
            assert stat.S_IMODE((root / role / private).stat().st_mode) == 0o600
    assert stat.S_IMODE((root / "ca" / "ca.key").stat().st_mode) == 0o600
    ks = KeySet(root, "uav1")
    assert list(ks.trusted()) == ["gcs"] and ks.uavs() == [1, 2] and ks.revoked() == set()


def test_init_refuses_to_overwrite_and_force_rotates(tmp_path):
    root = pki.init(tmp_path / "k", uavs=1)
    old = key_id(load_public(root / "gcs" / "sign.pub"))
    with pytest.raises(ValueError, match="already holds"):
        pki.init(root, uavs=1)
    pki.init(root, uavs=1, force=True)
    assert key_id(load_public(root / "gcs" / "sign.pub")) != old


def test_revoke_by_file_or_id_and_bad_ids(tmp_path):
    root = pki.init(tmp_path / "k", uavs=1)
    kid = pki.revoke(root, str(root / "gcs" / "sign.pub"))
    assert KeySet(root, "uav1").revoked() == {kid}
    with pytest.raises(ValueError, match="16-hex-digit"):
        pki.revoke(root, "not-a-key")
    assert any("revoked: " + kid in line for line in pki.show(root))


def test_bad_roles_and_folders(tmp_path):
    with pytest.raises(ValueError, match="role"):
        KeySet(tmp_path, "uav0")
    with pytest.raises(ValueError, match="not a key set"):
        KeySet(tmp_path, "uav1")


def test_dev_keys_reused_or_grown_and_insecure_resolves_to_nothing(tmp_path):
    a = dev_keys(tmp_path / "dev", 2)
    first = (a / "ca.pem").read_bytes()
    assert (dev_keys(tmp_path / "dev", 3) / "ca.pem").read_bytes() == first  # 3 are always made
    grown = dev_keys(tmp_path / "dev", 5)
    assert (grown / "uav5" / "tls.pem").exists() and (grown / "ca.pem").read_bytes() != first

    class Args:
        insecure, secure, keys, uavs = True, False, None, 3
    plan = resolve(Args, proxied=False)
    assert plan.keys is None and not plan.tls and "INSECURE" in plan.warnings[0]
    Args.insecure, Args.keys = False, str(tmp_path / "dev")
    assert resolve(Args, proxied=True).tls is False and resolve(Args, proxied=False).tls
