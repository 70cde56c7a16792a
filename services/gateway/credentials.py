"""Credentials files for a secured network: the gateway's users file and the edges' mesh config.

Zenoh's user/password authentication (``transport/auth/usrpwd``) is checked by whichever node
*accepts* a link, against its own dictionary: a node that has user/password configured and no
dictionary refuses every incoming link. The gateway holds every user; the UAV edges, which
accept links from each other (SkyNet), hold a dictionary of the UAV users only, given to them as a
Zenoh config file (``--config``). Files are written readable by their owner only.
"""

from __future__ import annotations

import json
import os
import secrets
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from protocol.acl import check_password, check_user, role_of


@dataclass(frozen=True)
class Credentials:
    """Generated credentials: ``passwords[user]``, the gateway's ``--users`` file and the edges' ``--config``."""

    passwords: dict[str, str]
    users_file: Path
    mesh_config: Path


def write_private(path: Path, text: str) -> Path:
    """Write ``text`` to ``path`` with mode 0600 (created that way, never world-readable)."""
    path = Path(path)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.chmod(path, 0o600)
    return path


def users_text(passwords: Mapping[str, str]) -> str:
    """The dictionary-file text: one ``user:password`` per line (validated)."""
    return "".join(f"{check_user(u)}:{check_password(p)}\n" for u, p in passwords.items())


def mesh_config_doc(dictionary_file: str | Path) -> dict:
    """The Zenoh config of an edge in an authenticated mesh.

    A users dictionary, so that it accepts links from the other edges, and gossip autoconnect
    ``greater-zid`` between peers: with the default (``always``) two edges that learn of each
    other at the same instant both dial, and with authentication on, the collision can leave the
    pair unlinked for good (seen in 3 runs of 12 on loopback); with ``greater-zid`` only one dials.
    """
    return {"transport": {"auth": {"usrpwd": {"dictionary_file": str(dictionary_file)}}},
            "scouting": {"gossip": {"autoconnect_strategy": {"peer": {"to_router": "always",
                                                                      "to_peer": "greater-zid"}}}}}


def _password(nbytes: int) -> str:
    """A URL-safe random password that does not start with '-' (a command line would read it as
    an option)."""
    while True:
        pw = secrets.token_urlsafe(nbytes)
        if not pw.startswith("-"):
            return pw


def generate(folder: str | Path, users: Iterable[str], nbytes: int = 18) -> Credentials:
    """Random passwords for ``users`` and their files in ``folder``.

    Writes ``users.txt`` (every user, for ``skynet gateway --users``), ``mesh-users.txt`` (the
    users whose role is ``uav``) and ``edge.json5`` (a Zenoh config pointing at the latter, for
    ``skynet edge --config``).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    names = list(users)
    if not names or len(set(names)) != len(names):
        raise ValueError("generate() wants a non-empty list of distinct user names")
    passwords = {check_user(u): _password(nbytes) for u in names}
    users_file = write_private(folder / "users.txt", users_text(passwords))
    uavs = {}
    for u, p in passwords.items():
        try:
            if role_of(u).role == "uav":
                uavs[u] = p
        except ValueError:
            pass
    mesh = write_private(folder / "mesh-users.txt", users_text(uavs))
    config = write_private(folder / "edge.json5", json.dumps(mesh_config_doc(mesh)))
    return Credentials(passwords, users_file, config)
