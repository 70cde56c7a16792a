"""``skynet keys``: a development fleet PKI.

Design notes: docs/security.md (services/keys.py).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import ipaddress
import os
import re
import shutil
import sys
import tempfile
from collections.abc import Iterable
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from protocol.cliconfig import show_defaults
from protocol.keyset import KeySet, check_role
from protocol.signing import key_id, load_public

#: the roles every key set has, besides the UAVs
SERVICE_ROLES = ("gateway", "gcs", "planner", "detector", "video", "web", "replay")
#: the roles whose certificates the router CA issues (what a client accepts at the other end of its dial)
ROUTER_ROLES = ("gateway",)
ROUTER_CA_CN = "SkyNet Inspect dev router CA"
#: who signs what the UAVs obey
COMMAND_SIGNERS = ("gcs",)
#: node certificate lifetime, days
NODE_DAYS = 30
#: CA certificate lifetime, days
CA_DAYS = 5 * 365
VALID_DAYS = NODE_DAYS
#: a development key set whose certificates expire within this many days is replaced (trustmode.dev_keys)
RENEW_DAYS = 2


def roles(uavs: int) -> list[str]:
    if not 1 <= uavs <= 255:
        raise ValueError("--uavs must be in 1..255")
    return [*SERVICE_ROLES, *(f"uav{i}" for i in range(1, uavs + 1))]


def _is_role(name: str) -> bool:
    try:
        check_role(name)
        return True
    except ValueError:
        return False


def _owner(path: Path) -> tuple[int, int] | None:
    """Whom a file root writes at ``path`` belongs to: the file it replaces, else its folder (None when not root).
    Root rewriting a user's key set (``docker compose exec keys skynet keys revoke /keys uav2``) leaves it
    theirs, private keys readable by them as before."""
    if os.geteuid() != 0:
        return None
    for p in (path, path.parent):
        try:
            st = p.stat()
        except FileNotFoundError:
            continue
        return st.st_uid, st.st_gid
    return None


def _write(path: Path, data: bytes, private: bool = False) -> None:
    """Write ``path`` whole or not at all (a temporary file renamed over it): a running gateway reads
    ``certs.txt`` and ``revoked.txt`` while they are rewritten, and an empty read would revoke everyone."""
    path.parent.mkdir(parents=True, exist_ok=True)
    owner = _owner(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)  # mode 0600, name unique
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        if not private:
            os.chmod(tmp, 0o644)
        if owner is not None:
            os.chown(tmp, *owner)
    except BaseException:
        os.unlink(tmp)
        raise
    os.replace(tmp, path)


def _pem_private(key) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _pem_public(key) -> bytes:
    return key.public_bytes(serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo)


def _write_identity(node: Path, key, cert: x509.Certificate) -> Ed25519PrivateKey:
    """Write a node's TLS key and certificate and a new signing key pair into ``node``; the signing key."""
    _write(node / "tls.key", _pem_private(key), private=True)
    _write(node / "tls.pem", cert.public_bytes(serialization.Encoding.PEM))
    sk = Ed25519PrivateKey.generate()
    _write(node / "sign.key", _pem_private(sk), private=True)
    _write(node / "sign.pub", _pem_public(sk.public_key()))
    return sk


def _write_names(folder: Path, names: Iterable[str]) -> None:
    """``certs.txt``: the common names the access control admits, one a line."""
    _write(folder / "certs.txt", "".join(f"{n}\n" for n in names).encode())


def _name(cn: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "SkyNet Inspect dev fleet"),
                      x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def make_ca(now: dt.datetime, days: int = CA_DAYS, cn: str = "SkyNet Inspect dev CA"):
    key = ec.generate_private_key(ec.SECP256R1())
    name = _name(cn)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                         content_commitment=False, key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    return key, cert


#: a DNS name a certificate may carry (RFC 1123 section 2.1 labels, at most 253 characters)
_LABEL = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)")


def san_name(name: str) -> x509.GeneralName:
    """``name`` as a SAN: an ``iPAddress`` for an IPv4/IPv6 address, else a ``dNSName``; ValueError otherwise."""
    with contextlib.suppress(ValueError):
        return x509.IPAddress(ipaddress.ip_address(name))
    if not (0 < len(name) <= 253 and all(_LABEL.fullmatch(label) for label in name.split("."))):
        raise ValueError(f"{name!r} is neither an IP address nor a host name")
    return x509.DNSName(name)


def parse_sans(specs: list[str] | tuple[str, ...]) -> dict[str, tuple[str, ...]]:
    """``["gateway=10.0.0.5,gw.example uav1=10.0.0.6", ...]`` -> ``{"gateway": ("10.0.0.5", "gw.example"), ...}``.

    Each spec is ``ROLE=NAME[,NAME...]``; one string may hold several, separated by whitespace (so a
    compose file can pass one variable); an empty string holds none. A role may be named more than once.
    ValueError names the bad spec: an unknown role, no ``=``, no name, or a name that is neither an
    address nor a host name.
    """
    out: dict[str, list[str]] = {}
    for spec in (part for text in specs for part in text.split()):
        role, sep, names = spec.partition("=")
        if not sep or not names.strip(","):
            raise ValueError(f"--san {spec!r}: expected ROLE=NAME[,NAME...], e.g. gateway=10.0.0.5,gw.example")
        check_role(role)
        for name in filter(None, names.split(",")):
            san_name(name)
            if name not in out.setdefault(role, []):
                out[role].append(name)
    return {r: tuple(n) for r, n in out.items()}


def make_node_cert(role: str, ca_key, ca_cert, now: dt.datetime, days: int = VALID_DAYS, hosts: tuple[str, ...] = (),
                   cn: str | None = None):
    """A TLS key and certificate with common name ``cn`` (default ``role``), for both ends of a mutual-TLS link;
    ``hosts`` are extra SANs (addresses or host names, :func:`san_name`)."""
    key = ec.generate_private_key(ec.SECP256R1())
    sans: list[x509.GeneralName] = []
    for h in (role, "localhost", "127.0.0.1", *hosts):
        san = san_name(h)
        if san not in sans:
            sans.append(san)
    cert = (x509.CertificateBuilder().subject_name(_name(cn or role)).issuer_name(ca_cert.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName(sans), critical=False)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256()))
    return key, cert


def init(folder: str | Path, uavs: int = 3, force: bool = False, days: int = VALID_DAYS,
         hosts: tuple[str, ...] = (), sans: dict[str, tuple[str, ...]] | None = None) -> Path:
    """Write a complete development key set to ``folder`` (see :mod:`protocol.keyset`); ``hosts`` are SANs
    of every certificate, ``sans`` (:func:`parse_sans`) of one role's."""
    folder = Path(folder)
    sans = sans or {}
    unknown = sorted(set(sans) - set(roles(uavs)))
    if unknown:
        raise ValueError(f"--san for {', '.join(unknown)}: not a node of a {uavs}-UAV key set")
    for h in hosts:
        san_name(h)
    if (folder / "ca.pem").exists():
        if not force:
            raise ValueError(f"{folder} already holds a key set (use --force to replace it)")
        for sub in ("ca", "trust", *(p.name for p in folder.iterdir() if p.is_dir() and _is_role(p.name))):
            shutil.rmtree(folder / sub, ignore_errors=True)
    folder.mkdir(parents=True, exist_ok=True)
    os.chmod(folder, 0o700)
    now = dt.datetime.now(dt.UTC)
    ca_key, ca_cert = make_ca(now, max(days, CA_DAYS))
    # gateways get their certificates from a CA of their own, the only one the clients trust for their dial: a
    # node certificate cannot stand in for the gateway (protocol.keyset, "tls_ca")
    router_key, router_cert = make_ca(now, max(days, CA_DAYS), ROUTER_CA_CN)
    _write(folder / "ca" / "ca.key", _pem_private(ca_key), private=True)
    _write(folder / "ca" / "node-ca.pem", ca_cert.public_bytes(serialization.Encoding.PEM))
    _write(folder / "ca" / "router-ca.key", _pem_private(router_key), private=True)
    _write(folder / "router-ca.pem", router_cert.public_bytes(serialization.Encoding.PEM))
    _write(folder / "ca.pem", ca_cert.public_bytes(serialization.Encoding.PEM)
           + router_cert.public_bytes(serialization.Encoding.PEM))
    for role in roles(uavs):
        issuer = (router_key, router_cert) if role in ROUTER_ROLES else (ca_key, ca_cert)
        sk = _write_identity(folder / role, *make_node_cert(role, *issuer, now, days, (*hosts, *sans.get(role, ()))))
        if role in COMMAND_SIGNERS:
            _write(folder / "trust" / f"{role}.pub", _pem_public(sk.public_key()))
    _write_names(folder, roles(uavs))
    if not (folder / "revoked.txt").exists():
        _write(folder / "revoked.txt", b"# revoked signing key ids and 'cert NAME' lines (skynet keys revoke)\n")
    return folder


def missing(folder: str | Path, uavs: int) -> list[str]:
    """The roles of a ``uavs``-UAV key set that ``folder`` has no certificate for."""
    folder = Path(folder)
    return [r for r in roles(uavs) if not (folder / r / "tls.pem").exists()]


def enlarge(folder: str | Path, uavs: int, days: int = VALID_DAYS) -> list[str]:
    """Issue the roles ``folder`` lacks (:func:`missing`) with its own CA, keeping every existing identity;
    the roles added. Needs the CA key (``ca/ca.key``; the router CA's roles are not issued so): a set without it (a vehicle's copy) is not enlarged
    (ValueError). Each role is written to a temporary folder and renamed into place, so two launchers
    enlarging the same set at once each install whole identities (the second rename of a role fails and
    its copy is dropped)."""
    import tempfile

    folder = Path(folder)
    lacking = missing(folder, uavs)
    if not lacking:
        return []
    router = [r for r in lacking if r in ROUTER_ROLES]
    if router:
        raise ValueError(f"{folder} lacks {', '.join(router)}: a router certificate comes only with a new key set")
    ca_key_path, ca_path = folder / "ca" / "ca.key", folder / "ca" / "node-ca.pem"
    if not ca_path.is_file():  # a set made before the router CA: its one CA
        ca_path = folder / "ca.pem"
    if not (ca_key_path.is_file() and ca_path.is_file()):
        raise ValueError(f"{folder} lacks {', '.join(lacking)} and has no CA key to issue them")
    ca_key = serialization.load_pem_private_key(ca_key_path.read_bytes(), password=None)
    ca_cert = x509.load_pem_x509_certificate(ca_path.read_bytes())
    now = dt.datetime.now(dt.UTC)
    added = []
    for role in lacking:
        tmp = Path(tempfile.mkdtemp(prefix=f".{role}-", dir=folder))
        _write_identity(tmp, *make_node_cert(role, ca_key, ca_cert, now, days))
        try:
            os.rename(tmp, folder / role)  # fails when another process installed it first
            added.append(role)
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
    if added and (folder / "certs.txt").exists():  # the new names admitted by the access control
        _write_names(folder, sorted({*KeySet(folder, "gcs").admitted(), *added}))
    return added


def expiring(folder: str | Path, within_days: float = RENEW_DAYS) -> bool:
    """Whether the CA or a node certificate of ``folder`` expires within ``within_days`` (or is unreadable)."""
    limit = dt.datetime.now(dt.UTC) + dt.timedelta(days=within_days)
    folder = Path(folder)
    try:
        for pem in (folder / "ca.pem", *sorted(folder.glob("*/tls.pem"))):
            if x509.load_pem_x509_certificate(pem.read_bytes()).not_valid_after_utc < limit:
                return True
    except (OSError, ValueError):
        return True
    return False


def _common_name(cert: x509.Certificate) -> str:
    value = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value
    return value.decode() if isinstance(value, bytes) else value


def _cn(cert_path: Path) -> str:
    return _common_name(x509.load_pem_x509_certificate(cert_path.read_bytes()))


def _set_certs(folder: Path, old: str, new: str | None) -> None:
    """Replace (or, ``new`` None, drop) ``old`` in ``certs.txt``."""
    names = [n for n in KeySet(folder, "gcs").admitted() if n != old] + ([new] if new else [])
    _write_names(folder, sorted(names))


def _append_revoked(folder: Path, lines: list[str]) -> None:
    path = folder / "revoked.txt"
    text = path.read_text() if path.exists() else ""
    if text and not text.endswith("\n"):
        text += "\n"
    _write(path, (text + "".join(f"{ln}\n" for ln in lines)).encode())


def revoke_node(folder: str | Path, role: str) -> list[str]:
    """Revoke node ``role``: its certificate's common name (the ACLs admit it no more) and its signing key; the
    lines added to ``revoked.txt``."""
    folder = Path(folder)
    check_role(role)
    node = folder / role
    if not (node / "tls.pem").is_file():
        raise ValueError(f"{folder}: no node {role!r}")
    lines = [f"cert {_cn(node / 'tls.pem')}", key_id(load_public(node / "sign.pub"))]
    _append_revoked(folder, lines)
    _set_certs(folder, lines[0][5:], None)
    for pub in (folder / "trust").glob(f"{role}.*pub"):  # a revoked signer is trusted no more
        if pub.name.split(".")[0] == role:
            pub.unlink()
    return lines


def reissue(folder: str | Path, role: str, days: int = NODE_DAYS) -> str:
    """A new certificate (common name ``role.gN``, the next generation, same SANs) and signing key for node
    ``role``, signed by the key set's CA; the old certificate and key are revoked. Returns the new common name."""
    folder = Path(folder)
    check_role(role)
    node = folder / role
    router = role in ROUTER_ROLES and (folder / "router-ca.pem").exists()
    ca_key_path = folder / "ca" / ("router-ca.key" if router else "ca.key")
    if not (node / "tls.pem").is_file():
        raise ValueError(f"{folder}: no node {role!r}")
    if not ca_key_path.is_file():
        raise ValueError(f"{folder}: no CA key ({ca_key_path}): re-issue where the CA key is kept")
    old_cert = x509.load_pem_x509_certificate((node / "tls.pem").read_bytes())
    old_cn = _cn(node / "tls.pem")
    gen = int(old_cn.rsplit(".g", 1)[1]) if ".g" in old_cn else 1
    new_cn = f"{role}.g{gen + 1}"
    ca_key = serialization.load_pem_private_key(ca_key_path.read_bytes(), password=None)
    ca_pem = folder / ("router-ca.pem" if router else "ca" / Path("node-ca.pem"))
    ca_cert = x509.load_pem_x509_certificate((ca_pem if ca_pem.exists() else folder / "ca.pem").read_bytes())
    try:
        old_sans = old_cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        hosts = tuple(str(n.value) for n in old_sans)
    except x509.ExtensionNotFound:
        hosts = ()
    now = dt.datetime.now(dt.UTC)
    old_kid = key_id(load_public(node / "sign.pub"))
    sk = _write_identity(node, *make_node_cert(role, ca_key, ca_cert, now, days, hosts, cn=new_cn))
    if role in COMMAND_SIGNERS:
        _write(folder / "trust" / f"{role}.pub", _pem_public(sk.public_key()))
    _append_revoked(folder, [f"cert {old_cn}", old_kid])
    _set_certs(folder, old_cn, new_cn)
    (node / "replay.json").unlink(missing_ok=True)
    return new_cn


def usable(folder: str | Path, uavs: int) -> bool:
    """Whether ``folder`` holds a key set covering ``uavs`` UAVs whose certificates are not about to expire."""
    folder = Path(folder)
    return ((folder / "ca.pem").exists() and (folder / "certs.txt").exists() and (folder / "router-ca.pem").exists()
            and all((folder / r / "tls.pem").exists() for r in roles(uavs)) and not expiring(folder))


def ensure(folder: str | Path, uavs: int) -> Path:
    """Reuse the key set in ``folder`` if it covers ``uavs`` UAVs (:func:`usable`; enlarged with its own CA when it
    lacks node roles, :func:`enlarge`), else make a new one."""
    folder = Path(folder)
    if (folder / "router-ca.pem").exists() and (folder / "ca" / "ca.key").exists() and not expiring(folder):
        with contextlib.suppress(ValueError):  # not enlargeable: a new set below
            enlarge(folder, uavs)
    if usable(folder, uavs):
        return folder
    return init(folder, uavs, force=True)


def revoke(folder: str | Path, what: str) -> str:
    """Revoke a node (``uav2``: :func:`revoke_node`) or add a key id (or the id of a public key file) to
    ``revoked.txt``; returns what was revoked."""
    if not Path(what).is_file() and (Path(folder) / what / "tls.pem").is_file():
        return ", ".join(revoke_node(folder, what))
    kid = key_id(load_public(what)) if Path(what).is_file() else what.strip().lower()
    if not re.fullmatch(r"[0-9a-f]{16}", kid):
        raise ValueError(f"expected a 16-hex-digit key id or a public key file, got {what!r}")
    KeySet(folder, "gcs")  # validates the folder
    path = Path(folder) / "revoked.txt"
    text = path.read_text() if path.exists() else ""
    _write(path, (text + f"{kid}\n").encode())
    return kid


def show(folder: str | Path) -> list[str]:
    folder = Path(folder)
    lines = []
    for node in sorted(p for p in folder.iterdir() if p.is_dir() and (p / "tls.pem").exists()):
        check_role(node.name)
        cert = x509.load_pem_x509_certificate((node / "tls.pem").read_bytes())
        cn = _common_name(cert)
        lines.append(f"{node.name:10} CN={cn:10} sign key {key_id(load_public(node / 'sign.pub'))}  "
                     f"TLS until {cert.not_valid_after_utc:%Y-%m-%d}")
    ks = KeySet(folder, "gcs")
    lines.append(f"trusted signers: {', '.join(f'{n} ({len(k)} key)' for n, k in ks.trusted().items()) or 'none'}")
    lines.append(f"revoked: {', '.join(sorted(ks.revoked())) or 'none'}")
    return lines


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="skynet keys", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="action", required=True)
    p = sub.add_parser("init", help="write a development key set (CA, per-node TLS certificates and signing keys)")
    p.add_argument("dir")
    p.add_argument("--uavs", type=int, default=3, metavar="N", help="UAVs 1..N get a certificate and a signing key")
    p.add_argument("--days", type=int, default=NODE_DAYS, help=f"node certificate validity (CA: {CA_DAYS} days)")
    p.add_argument("--host", action="append", default=[], help="extra SAN (address or name) on every certificate")
    p.add_argument("--san", action="append", default=[], metavar="ROLE=NAME[,NAME...]",
                   help="extra SANs on one role's certificate, e.g. gateway=10.0.0.5,gw.example (repeatable; "
                        "SKYNET_SANS in the environment adds more, space-separated)")
    p.add_argument("--force", action="store_true", help="replace an existing key set (rotation)")
    p = sub.add_parser("revoke", help="revoke a node (its certificate and signing key) or one signing key")
    p.add_argument("dir")
    p.add_argument("key", help="a node (uav2, planner, ...), a key id (16 hex digits) or a public key file")
    p = sub.add_parser("reissue", help="a new certificate and signing key for one node, same CA; the old ones revoked")
    p.add_argument("dir")
    p.add_argument("node", help="uav2, planner, ...")
    p.add_argument("--days", type=int, default=NODE_DAYS, help="certificate validity")
    p = sub.add_parser("show", help="list the nodes, key ids and certificate expiry")
    p.add_argument("dir")
    return show_defaults(parser)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.action == "init":
        try:
            sans = parse_sans([*args.san, os.environ.get("SKYNET_SANS", "")])
            folder = init(args.dir, args.uavs, args.force, args.days, tuple(args.host), sans)
        except ValueError as exc:
            print(f"skynet keys: {exc}", file=sys.stderr)
            return 2
        print(f"key set written to {folder} (CA key in {folder / 'ca' / 'ca.key'}: keep it off the vehicles)")
        for role, names in sorted(sans.items()):
            print(f"  {role}: extra SANs {', '.join(names)}")
    elif args.action in ("revoke", "reissue"):
        try:
            if args.action == "revoke":
                print(f"revoked {revoke(args.dir, args.key)} (a running gateway applies it within two periods, "
                      f"a running edge within about two seconds)")
            else:
                print(f"{args.node}: new certificate {reissue(args.dir, args.node, args.days)}; give the node its "
                      f"folder (it restarts with it) and every node certs.txt and revoked.txt (a running gateway "
                      f"applies them within two periods, a running edge within about two seconds)")
        except (ValueError, OSError) as exc:
            print(f"skynet keys: {exc}", file=sys.stderr)
            return 2
    else:
        print("\n".join(show(args.dir)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
