"""The key set of a docker compose network: reused, made once, or refused.

Design notes: docs/security.md (services/composekeys.py).
"""

from __future__ import annotations

import argparse
import ipaddress
import os
import sys
from pathlib import Path

from cryptography import x509

from services.keys import enlarge, init, parse_sans, roles

EXIT_REFUSED = 2


def missing_roles(folder: Path, uavs: int) -> list[str]:
    """The roles of a ``uavs``-UAV network without a certificate in ``folder``."""
    return [r for r in roles(uavs) if not (folder / r / "tls.pem").is_file()]


def missing_sans(folder: Path, hosts: list[str], role: str = "gateway") -> list[str]:
    """The ``hosts`` that ``role``'s certificate does not name (DNS or IP SANs)."""
    cert = x509.load_pem_x509_certificate((folder / role / "tls.pem").read_bytes())
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return list(hosts)
    names = {*san.get_values_for_type(x509.DNSName), *(str(a) for a in san.get_values_for_type(x509.IPAddress))}
    return [h for h in hosts if _canonical(h) not in names]


def _canonical(name: str) -> str:
    try:
        return str(ipaddress.ip_address(name))
    except ValueError:
        return name


def _chown_tree(folder: Path, ref: Path) -> None:
    st = ref.stat()
    for dirpath, dirnames, filenames in os.walk(folder):
        for name in [dirpath, *(os.path.join(dirpath, n) for n in dirnames + filenames)]:
            os.chown(name, st.st_uid, st.st_gid)


def prepare(folder: Path, uavs: int, hosts: list[str], owner_of: Path | None = None,
            sans: dict[str, tuple[str, ...]] | None = None) -> tuple[str, list[str]]:
    """(``"reused"`` | ``"made"``, warnings); ValueError when the folder holds an incomplete set."""
    folder = Path(folder)
    warnings: list[str] = []
    sans = sans or {}
    if not (folder / "ca.pem").exists():
        if folder.exists() and any(folder.iterdir()):
            raise ValueError(f"{folder} is not empty but holds no ca.pem: not a key set, left alone")
        init(folder, uavs, hosts=tuple(hosts), sans=sans)
        if owner_of is not None:
            _chown_tree(folder, owner_of)
        return "made", warnings
    lacking = missing_roles(folder, uavs)
    # an older set without the tools' identities (they dial, they need no host names): issued by its own CA;
    # a set lacking a node's identity (which may need its host's names) is refused as before
    if lacking and set(lacking) <= {"video", "web", "replay"} and (folder / "ca" / "ca.key").is_file():
        added = enlarge(folder, uavs)
        if owner_of is not None and added:
            _chown_tree(folder, owner_of)
        warnings += [f"the key set lacked {', '.join(added)}: issued by its own CA"] if added else []
        lacking = missing_roles(folder, uavs)
    if lacking:
        raise ValueError(f"{folder}: the key set has no certificate for {', '.join(lacking)} "
                         f"(make a complete one: skynet keys init DIR --uavs {uavs} --force)")
    unnamed = missing_sans(folder, hosts)
    if unnamed:
        warnings.append(f"the gateway's certificate does not name {', '.join(unnamed)}: links through those "
                        "impairment side-cars will fail the TLS name check (docs/compose.md)")
    for role, names in sorted(sans.items()):
        unnamed = missing_sans(folder, list(names), role)
        if unnamed:
            warnings.append(f"{role}'s certificate does not name {', '.join(unnamed)}: a link dialled there will "
                            f"fail the TLS name check (make the set again: skynet keys init DIR --force "
                            f"--san {role}={','.join(names)} ...)")
    return "reused", warnings


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m services.composekeys", description=__doc__.split("\n\n")[0])
    p.add_argument("dir", type=Path)
    p.add_argument("--uavs", type=int, default=3)
    p.add_argument("--host", action="append", default=[], help="extra SAN on every certificate of a new set")
    p.add_argument("--san", action="append", default=[], metavar="ROLE=NAME[,NAME...]",
                   help="extra SANs on one role's certificate of a new set (space-separated specs allowed)")
    p.add_argument("--owner-of", type=Path, default=None, metavar="PATH", help="give a new set to PATH's owner")
    return p


def main(argv: list[str] | None = None) -> int:
    a = build_parser().parse_args(argv)
    try:
        what, warnings = prepare(a.dir, a.uavs, a.host, a.owner_of, parse_sans(a.san))
    except (ValueError, OSError) as exc:
        print(f"keys: REFUSED: {exc}", file=sys.stderr, flush=True)
        return EXIT_REFUSED
    for w in warnings:
        print(f"keys: WARNING: {w}", file=sys.stderr, flush=True)
    print(f"keys: {what} the key set in {a.dir} ({a.uavs} UAVs): mounted read-only into every service", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
