"""skynet keys: the development PKI is complete, private keys are private, CN = role, chain to the CA."""

from __future__ import annotations

import os
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
    ca, router = x509.load_pem_x509_certificates((root / "ca.pem").read_bytes())  # the node CA, the router CA
    assert x509.load_pem_x509_certificate((root / "router-ca.pem").read_bytes()) == router
    for role in ("gateway", "gcs", "planner", "detector", "uav1", "uav2"):
        cert = x509.load_pem_x509_certificate((root / role / "tls.pem").read_bytes())
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == role
        cert.verify_directly_issued_by(router if role == "gateway" else ca)  # only gateways by the router CA
        for private in ("tls.key", "sign.key"):
            assert stat.S_IMODE((root / role / private).stat().st_mode) == 0o600
    assert stat.S_IMODE((root / "ca" / "ca.key").stat().st_mode) == 0o600
    assert stat.S_IMODE((root / "ca" / "router-ca.key").stat().st_mode) == 0o600
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
    # enlarged by its own CA: the identities already handed out stay valid
    assert (grown / "uav5" / "tls.pem").exists() and (grown / "ca.pem").read_bytes() == first

    class Args:
        insecure, secure, keys, uavs, impair = True, False, None, 3, []
    plan = resolve(Args, proxied=False)
    assert plan.keys is None and not plan.tls and "INSECURE" in plan.warnings[0]
    Args.insecure, Args.keys = False, str(tmp_path / "dev")
    assert resolve(Args, proxied=True).tls and resolve(Args, proxied=False).tls  # one model, impaired or not
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dev"], "no debris beside the key set"


def _sans(cert_path) -> set[str]:
    cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    return {*san.get_values_for_type(x509.DNSName), *(str(a) for a in san.get_values_for_type(x509.IPAddress))}


def test_parse_sans_takes_roles_lists_and_space_separated_specs_and_names_bad_ones():
    assert pki.parse_sans(["gateway=10.0.0.5,gw.example", "uav1=10.0.0.6 uav2=fd00::2", "", "gateway=10.0.0.5"]) == {
        "gateway": ("10.0.0.5", "gw.example"), "uav1": ("10.0.0.6",), "uav2": ("fd00::2",)}
    for bad, why in [("gateway", "ROLE=NAME"), ("gateway=", "ROLE=NAME"), ("pilot=10.0.0.5", "role must be"),
                     ("uav0=10.0.0.5", "role must be"), ("gateway=under_score", "neither"), ("gateway=10.0.0.5 name", "ROLE=NAME"),
                     ("gateway=-bad.example", "neither"), ("gateway=a..b", "neither"), ("uav1=" + "a" * 64, "neither")]:
        with pytest.raises(ValueError, match=why):
            pki.parse_sans([bad])


def test_a_role_san_goes_on_that_role_only_and_an_unknown_node_is_refused(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SKYNET_SANS", "uav2=10.0.0.7")
    assert pki.main(["init", str(tmp_path / "k"), "--uavs", "2", "--san", "gateway=10.0.0.5,gw.example",
                     "--host", "netem-uav2"]) == 0
    assert "gateway: extra SANs 10.0.0.5, gw.example" in capsys.readouterr().out
    root = tmp_path / "k"
    base = {"localhost", "127.0.0.1", "netem-uav2"}
    assert _sans(root / "gateway" / "tls.pem") == base | {"gateway", "10.0.0.5", "gw.example"}
    assert _sans(root / "uav2" / "tls.pem") == base | {"uav2", "10.0.0.7"}
    assert _sans(root / "uav1" / "tls.pem") == base | {"uav1"}
    monkeypatch.delenv("SKYNET_SANS")
    assert pki.main(["init", str(tmp_path / "k3"), "--uavs", "2", "--san", "uav3=10.0.0.8"]) == 2
    assert "uav3: not a node of a 2-UAV key set" in capsys.readouterr().err and not (tmp_path / "k3").exists()
    with pytest.raises(ValueError, match="neither"):
        pki.init(tmp_path / "k4", uavs=1, hosts=("bad name",))


def test_an_extra_ip_san_verifies_for_that_address_in_a_real_tls_handshake(tmp_path, group):
    """A real gateway process listens on tls/127.0.0.2 (a loopback address the default SANs do not name);
    a client with uav1's certificate dials that address: admitted when the gateway's certificate carries
    it (--san gateway=127.0.0.2), refused at the handshake when it does not (the control)."""
    import socket

    import zenoh

    from protocol.bus import Bus, BusConfig
    from services.orchestration.process import free_port

    named = pki.init(tmp_path / "named", uavs=1, sans=pki.parse_sans(["gateway=127.0.0.2"]))
    plain = pki.init(tmp_path / "plain", uavs=1)
    assert "127.0.0.2" in _sans(named / "gateway" / "tls.pem") and "127.0.0.2" not in _sans(plain / "gateway" / "tls.pem")
    for root, admitted in ((named, True), (plain, False)):
        port = free_port(socket.SOCK_STREAM)
        where = f"tls/127.0.0.2:{port}"
        gw = group.start(f"gateway-{root.name}", ["gateway", "--fleet", "test", "--keys", str(root), "--listen", where])
        assert gw.wait_ready(20), "\n".join(gw.lines)
        ks = KeySet(root, "uav1")
        config = BusConfig(mode="client", connect=[where], tls_ca=str(ks.ca), tls_cert=str(ks.tls_cert),
                           tls_key=str(ks.tls_key), connect_timeout_s=3.0)
        try:
            with Bus(config, "test", "uav1") as bus:
                linked = bool(bus.routers())
        except zenoh.ZError:
            linked = False
        assert linked is admitted, (root.name, gw.lines[-10:])


def test_an_older_set_without_the_tools_identities_is_enlarged_by_its_own_ca(tmp_path):
    folder = pki.init(tmp_path / "old", 3)
    gcs_cert = (folder / "gcs" / "tls.pem").read_bytes()
    import shutil
    for role in ("video", "web", "replay"):  # as a key set made before the tools had identities
        shutil.rmtree(folder / role)
    assert pki.missing(folder, 3) == ["video", "web", "replay"]
    assert dev_keys(folder, 3) == folder
    assert pki.missing(folder, 3) == [] and (folder / "gcs" / "tls.pem").read_bytes() == gcs_cert
    ca = x509.load_pem_x509_certificate((folder / "ca.pem").read_bytes())
    for role in ("video", "web", "replay"):
        cert = x509.load_pem_x509_certificate((folder / role / "tls.pem").read_bytes())
        assert cert.issuer == ca.subject
        cert.verify_directly_issued_by(ca)  # raises if another CA signed it
        assert oct((folder / role / "tls.key").stat().st_mode & 0o777) == "0o600"
    assert not [p for p in folder.iterdir() if p.name.startswith(".")]  # no temporary folder left


def test_enlarging_needs_the_ca_key_and_says_so(tmp_path):
    folder = pki.init(tmp_path / "vehicle", 1)
    import shutil
    shutil.rmtree(folder / "ca")
    shutil.rmtree(folder / "web")
    with pytest.raises(ValueError, match="no CA key"):
        pki.enlarge(folder, 1)


def test_dev_keys_grows_twice_in_one_process_and_under_concurrent_launchers_leaving_nothing_behind(tmp_path):
    import threading

    for n in (1, 4, 5):  # two rotations in one process: no name collision
        assert (dev_keys(tmp_path / "dev", n) / f"uav{max(n, 3)}" / "tls.pem").exists()
    cas: list[bytes] = []

    def launch() -> None:
        cas.append((dev_keys(tmp_path / "shared", 4) / "ca.pem").read_bytes())

    threads = [threading.Thread(target=launch) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(cas) == 4 and len(set(cas)) == 1, "concurrent launchers ended with different key sets"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dev", "shared"], list(tmp_path.iterdir())


def test_reissue_gives_a_new_generation_and_revokes_the_old_certificate_and_key(tmp_path):
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    folder = pki.init(tmp_path / "k", uavs=2, hosts=("gw.example",))
    assert pki.reissue(folder, "uav2") == "uav2.g2" and pki.reissue(folder, "uav2") == "uav2.g3"
    cert = x509.load_pem_x509_certificate((folder / "uav2" / "tls.pem").read_bytes())
    assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == "uav2.g3"
    assert "gw.example" in _sans(folder / "uav2" / "tls.pem")  # the SANs carry over
    ks = KeySet(folder, "uav1")
    assert ks.revoked_certs() == {"uav2", "uav2.g2"} and "uav2.g3" in ks.admitted()
    life = cert.not_valid_after_utc - cert.not_valid_before_utc
    assert life.days <= pki.NODE_DAYS
    pki.reissue(folder, "gcs")  # the command signer: trust/ follows, the old key is revoked
    assert len(KeySet(folder, "uav1").trusted()["gcs"]) == 1 and len(ks.revoked()) == 3
    with pytest.raises(ValueError, match="no node"):
        pki.reissue(folder, "uav7")


@pytest.mark.skipif(os.geteuid() != 0, reason="changing a file's owner needs root")
def test_root_revoking_and_reissuing_in_a_users_set_leaves_every_file_theirs(tmp_path):
    # compose: the keys service runs as root on the user's bind-mounted set (docs/compose.md)
    folder = pki.init(tmp_path / "k", uavs=2)
    uid, gid = 4321, 4322
    for p in [folder, *folder.rglob("*")]:
        os.chown(p, uid, gid)
    pki.revoke(folder, "uav1")
    pki.reissue(folder, "uav2")
    pki.reissue(folder, "gcs")
    owners = {(p.relative_to(folder).as_posix(), p.stat().st_uid, p.stat().st_gid) for p in folder.rglob("*")}
    assert {(o[1], o[2]) for o in owners} == {(uid, gid)}, sorted(o for o in owners if o[1:] != (uid, gid))
    assert stat.S_IMODE((folder / "uav2" / "tls.key").stat().st_mode) == 0o600


def test_revoked_names_and_admitted_names_are_read_and_checked(tmp_path):
    folder = pki.init(tmp_path / "k", uavs=2)
    ks = KeySet(folder, "gateway")
    assert ks.admitted() == ["gateway", "gcs", "planner", "detector", "video", "web", "replay", "uav1", "uav2"]
    assert "cert uav2" in pki.revoke(folder, "uav2")
    assert ks.revoked_certs() == {"uav2"} and "uav2" not in ks.admitted() and len(ks.revoked()) == 1
    (folder / "certs.txt").unlink()  # an older key set: every node folder's role, less the revoked ones
    assert "uav1" in ks.admitted() and "uav2" not in ks.admitted()
    (folder / "revoked.txt").write_text("cert not a name!\n")
    with pytest.raises(ValueError, match="line 1"):
        ks.revoked_certs()
    with pytest.raises(ValueError, match="no node"):
        pki.revoke_node(folder, "uav9")


def test_an_edge_acl_leaves_out_a_revoked_uav_and_names_a_reissued_one(tmp_path):
    import argparse

    from edge.trust import secure_setup

    folder = pki.init(tmp_path / "k", uavs=3)
    pki.revoke(folder, "uav3")
    pki.reissue(folder, "uav2")
    args = argparse.Namespace(uav=1, fleet="f", keys=str(folder), insecure=False, trust_window=10.0,
                              replay_state=None, mesh_uavs=3, listen=["tls/127.0.0.1:0"], connect=[])
    _, admission = secure_setup(args)
    assert admission is not None
    acl = admission.access_control()
    names = {n for s in acl["subjects"] for n in s["cert_common_names"]}
    assert names == {"gateway", "uav1", "uav2.g2"}, names
