"""Attaching a tool to a running network in one step: the network's description, written and read.

Design notes: docs/operator-view.md (services/attach.py).
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import logging
import os
import socket
import time
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field

from protocol import keys
from protocol.bus import BusMode, BusOptions
from protocol.cliconfig import Cli

log = logging.getLogger("skynet.attach")

#: where a launcher describes its network (relative to the working folder)
NETWORK_FILE = Path(".skynet") / "network.json"
#: an environment variable naming another description file
NETWORK_ENV = "SKYNET_NETWORK"
#: the description's format version
VERSION = 1
#: the largest description read (it is a few hundred bytes; anything bigger is not one)
MAX_BYTES = 64 * 1024


class AttachError(ValueError):
    """A tool cannot attach to the running network; the message says what is missing, in one line."""


def network_path(explicit: str | Path | None = None) -> Path:
    """The description file: ``explicit``, else ``$SKYNET_NETWORK``, else :data:`NETWORK_FILE`."""
    return Path(explicit or os.environ.get(NETWORK_ENV) or NETWORK_FILE)


def ca_fingerprint(key_folder: str | Path) -> str | None:
    """SHA-256 of the key set's ``ca.pem`` (hex), None when there is none."""
    try:
        return hashlib.sha256((Path(key_folder) / "ca.pem").read_bytes()).hexdigest()
    except OSError:
        return None


def describe(fleet: str, endpoints: list[str], key_folder: str | Path | None, tls: bool,
             pid: int | None = None) -> dict[str, Any]:
    """The description of a running network (JSON-ready): endpoints and the key set's folder, no secret."""
    keys.fleet_root(fleet)
    folder = None if key_folder is None else str(Path(key_folder).resolve())
    return {"version": VERSION, "fleet": fleet, "replay_fleet": keys.replay_fleet(fleet),
            "endpoints": list(endpoints), "keys": folder, "tls": bool(tls),
            "ca_sha256": None if folder is None else ca_fingerprint(folder),
            "host": socket.gethostname(), "pid": os.getpid() if pid is None else pid, "started": time.time()}


def write(path: str | Path, desc: dict[str, Any]) -> Path:
    """Write ``desc`` to ``path`` atomically (a temporary file renamed into place)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(desc, indent=1) + "\n")
    os.replace(tmp, path)
    return path


def remove(path: str | Path, pid: int | None = None) -> bool:
    """Remove the description at ``path`` if this process (``pid``) wrote it; True if removed. The
    ``.skynet`` folder goes too when it is left empty."""
    path = Path(path)
    pid = os.getpid() if pid is None else pid
    try:
        if json.loads(path.read_text()).get("pid") != pid:
            return False  # another launcher's (it started after us in the same folder)
        path.unlink()
    except (OSError, ValueError, AttributeError):
        return False
    with contextlib.suppress(OSError):
        path.parent.rmdir()
    return True


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def read(path: str | Path) -> dict[str, Any]:
    """The description at ``path``, checked; AttachError saying what is wrong (none there, not one, stale)."""
    path = Path(path)
    if not path.is_file():
        raise AttachError(f"no network running here: no {path} (start one with `skynet up` in this folder, "
                          f"or give -e ENDPOINT, or --network FILE / {NETWORK_ENV})")
    try:
        raw = path.read_bytes()[:MAX_BYTES + 1]
        if len(raw) > MAX_BYTES:
            raise ValueError(f"over {MAX_BYTES} bytes")
        desc = json.loads(raw)
        if not isinstance(desc, dict):
            raise ValueError("not an object")
        fleet, eps = desc.get("fleet"), desc.get("endpoints")
        keys.fleet_root(fleet)
        if not (isinstance(eps, list) and eps and all(isinstance(e, str) and 0 < len(e) < 256 for e in eps)):
            raise ValueError("no endpoints")
        if desc.get("keys") is not None and not isinstance(desc["keys"], str):
            raise ValueError("keys is not a folder name")
        pid = desc.get("pid")
        if not isinstance(pid, int) or isinstance(pid, bool):
            raise ValueError("no launcher pid")
    except (ValueError, TypeError) as exc:
        raise AttachError(f"{path} is not a network description ({exc})") from None
    if desc.get("host") == socket.gethostname() and not _alive(pid):
        raise AttachError(f"no network running here: {path} describes one whose launcher (pid {pid}) has ended; "
                          "start it again with `skynet up`")
    return desc


def explicit_fleet(argv: list[str] | None) -> bool:
    """True when ``--fleet`` was on the command line (not argparse's default)."""
    return any(a == "--fleet" or a.startswith("--fleet=") for a in (argv or []))


def attach(args: argparse.Namespace, role: str, argv: list[str] | None = None) -> dict[str, Any] | None:
    """Fill ``args``'s bus options from the running network's description, for the tool ``role``.

    Nothing is done (None) when the user said where to connect (``-e``/``--config``) or asked for
    multicast scouting. Otherwise the description (``args.network``, :func:`network_path`) gives the
    gateway's endpoints (a multilink pair: ``--multilink``), the fleet (unless ``--fleet`` was given: it
    must then be the network's fleet or its replay fleet) and the key set (unless ``--keys`` was given: it
    must have the same CA). Returns the description; AttachError when the tool cannot attach.
    """
    if args.connect or args.config or args.scouting:
        if args.network is not None:  # two answers to "where is the network": say so rather than pick one
            raise AttachError("--network: not with -e/--connect, -c/--config or --scouting (each says where the "
                              "network is)")
        return None
    path = network_path(args.network)
    desc = read(path)
    fleet = desc["fleet"]
    if explicit_fleet(argv):
        allowed = (fleet, keys.replay_fleet(fleet))
        if args.fleet not in allowed:
            raise AttachError(f"--fleet {args.fleet}: the network in {path} carries fleet {fleet} (and replays "
                              f"under {allowed[1]}), not {args.fleet}")
    else:
        args.fleet = fleet
    folder = desc.get("keys")
    if args.keys and folder:
        mine, theirs = ca_fingerprint(args.keys), desc.get("ca_sha256")
        if mine is None:
            raise AttachError(f"--keys {args.keys}: not a key set (no ca.pem)")
        if theirs and mine != theirs:
            raise AttachError(f"--keys {args.keys} is not the running network's key set (another CA); its "
                              f"key set is {folder}")
    elif folder and not args.keys:
        args.keys = folder
    if args.keys and desc.get("tls"):
        node = Path(args.keys) / role
        if not (node / "tls.pem").is_file():
            raise AttachError(f"the key set {args.keys} has no identity for {role} (an older set: start the "
                              f"network again, which enlarges it, or `skynet keys init --force`)")
    args.connect = list(desc["endpoints"])
    args.multilink = True
    args.mode = "client"
    log.info("attaching to the network in %s: fleet %s at %s%s", path, args.fleet, " ".join(args.connect),
             f" with {role}'s identity in {args.keys}" if args.keys and desc.get("tls") else "")
    return desc


def add_network_arg(parser: argparse.ArgumentParser) -> None:
    """``--network FILE``: the running network's description (default :data:`NETWORK_FILE`)."""
    parser.add_argument("--network", default=None, metavar="FILE",
                        help=f"the running network's description, used when no -e/--config is given "
                             f"(default: ${NETWORK_ENV} or {NETWORK_FILE}, written by skynet up/mission; not with "
                             "-e/--config)")


def explain_open_error(exc: BaseException, args: argparse.Namespace, desc: dict[str, Any] | None, role: str) -> str:
    """One line for a session that did not open: what was tried and what is likely missing."""
    text = " ".join(str(exc).split())
    where = " ".join(args.connect) or "(no endpoint)"
    if "No peer specified" in text or (not args.connect and not args.config):
        return ("no gateway to connect to: start a network with `skynet up` in this folder (the tools find it "
                "by .skynet/network.json), or give -e ENDPOINT")
    if "Timeout" in text or "Unable to connect" in text:
        if desc is not None:
            return (f"the network's gateway at {where} did not answer (is the network in {network_path(args.network)} "
                    f"still running? {role} used the key set {args.keys or '(none)'})")
        tls = any(e.startswith("tls/") for e in args.connect)
        hint = (f" with {role}'s identity in {args.keys}: is it this network's key set?" if tls and args.keys
                else " (tls/ endpoints need --keys)" if tls else "")
        return f"no gateway answered at {where}{hint}"
    return text[:300]


def open_bus(args: argparse.Namespace, role: str, argv: list[str] | None, name: str | None = None):
    """The tool's session: attached (:func:`attach`) and opened with its ``role``'s identity; AttachError
    (one line) when it cannot attach or Zenoh refuses to open."""
    from protocol.bus import Bus, config_from_args

    desc = attach(args, role, argv)
    config = config_from_args(args, role=role)
    try:
        return Bus(config, fleet=args.fleet, name=name or role)
    except Exception as exc:
        if type(exc).__name__ != "ZError":
            raise
        raise AttachError(explain_open_error(exc, args, desc, role)) from None


class AttachOptions(BusOptions):
    """The session options of a tool that attaches to a running network (:func:`open_bus`): video, web."""

    mode: BusMode = "client"
    network: Annotated[str | None, Cli(metavar="FILE")] = Field(
        default=None, description=f"the running network's description, used when no -e/--config is given "
                                  f"(default: ${NETWORK_ENV} or {NETWORK_FILE}, written by skynet up/mission; not "
                                  "with -e/--config)")
