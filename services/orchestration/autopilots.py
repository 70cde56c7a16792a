"""Real autopilots from the launcher: ``--autopilot uavN=ENDPOINT``, checked and normalised (pure, no I/O).

Design notes: docs/hardware-mavlink.md (services/orchestration/autopilots.py).
"""

from __future__ import annotations

import re

__all__ = ["normalise_endpoint", "parse_autopilot", "autopilot_endpoints", "NETWORK_SCHEMES"]

#: pymavlink's network connection prefixes (``mavutil.mavlink_connection``)
NETWORK_SCHEMES = ("udpin", "udpout", "udp", "udpbcast", "tcp", "tcpin")
#: a host: a name, an IPv4 address, or an IPv6 address in brackets
_HOST = re.compile(r"[A-Za-z0-9._-]{1,253}|\[[0-9A-Fa-f:.]{2,45}\]")
#: a serial device: an absolute path without the separators of the forms above
_DEVICE = re.compile(r"/[A-Za-z0-9._/+-]{1,200}")
#: the baud rates a serial endpoint may name
_BAUD = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 111100, 115200, 230400, 256000, 460800, 500000, 921600,
         1000000, 1500000, 2000000, 3000000)


def _show(text: str) -> str:
    """A user's text for an error message: printable, bounded."""
    return repr(text[:80] + ("..." if len(text) > 80 else ""))


def _baud(text: str, endpoint: str) -> int:
    if not text.isdigit() or int(text) not in _BAUD:
        raise ValueError(f"endpoint {_show(endpoint)}: baud rate {_show(text)} is not one of "
                         f"{', '.join(map(str, _BAUD))}")
    return int(text)


def normalise_endpoint(text: str) -> str:
    """``text`` as the pymavlink connection string the edge opens; ValueError (one line) for anything else."""
    if not isinstance(text, str) or not text or len(text) > 256 or not text.isprintable() or text != text.strip():
        raise ValueError(f"endpoint {_show(str(text))}: expected udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, "
                         "/dev/DEVICE[,BAUD] or serial:/dev/DEVICE[:BAUD]")
    scheme, sep, rest = text.partition(":")
    if text.startswith("/"):  # pymavlink's serial form: DEVICE[,BAUD]
        device, comma, baud = text.partition(",")
        if not _DEVICE.fullmatch(device) or "//" in device:
            raise ValueError(f"endpoint {_show(text)}: {_show(device)} is not a device path")
        return f"{device},{_baud(baud, text)}" if comma else device
    if sep and scheme == "serial":
        device, colon, baud = rest.partition(":")
        if not _DEVICE.fullmatch(device) or "//" in device:
            raise ValueError(f"endpoint {_show(text)}: {_show(device)} is not a device path")
        return f"{device},{_baud(baud, text)}" if colon else device
    if sep and scheme in NETWORK_SCHEMES:
        host, colon, port = rest.rpartition(":")
        if not colon or not _HOST.fullmatch(host):
            raise ValueError(f"endpoint {_show(text)}: expected {scheme}:HOST:PORT")
        if not port.isdigit() or not 1 <= int(port) <= 65535:
            raise ValueError(f"endpoint {_show(text)}: port {_show(port)} is not in 1..65535")
        return f"{scheme}:{host}:{int(port)}"
    raise ValueError(f"endpoint {_show(text)}: expected udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, "
                     "/dev/DEVICE[,BAUD] or serial:/dev/DEVICE[:BAUD]")


def parse_autopilot(text: str) -> tuple[int, str]:
    """``uavN=ENDPOINT`` -> (N, the normalised endpoint); ValueError (one line) for a malformed one."""
    name, eq, endpoint = str(text).partition("=")
    m = re.fullmatch(r"uav([0-9]{1,3})", name.strip())
    if not eq or m is None:
        raise ValueError(f"--autopilot {_show(str(text))}: expected uavN=ENDPOINT, e.g. uav1=udpin:0.0.0.0:14550")
    try:
        return int(m.group(1)), normalise_endpoint(endpoint)
    except ValueError as exc:
        raise ValueError(f"--autopilot {name.strip()}: {exc}") from None


def autopilot_endpoints(values: list[str], uavs: int) -> dict[int, str]:
    """UAV -> its autopilot's endpoint, from the repeatable ``--autopilot uavN=ENDPOINT``: each N in 1..``uavs``
    at most once, no endpoint given to two UAVs (one port or one device is one autopilot's link)."""
    out: dict[int, str] = {}
    owner: dict[str, int] = {}
    for text in values:
        uav, endpoint = parse_autopilot(text)
        if not 1 <= uav <= uavs:
            raise ValueError(f"--autopilot uav{uav}: the fleet has UAVs 1..{uavs} (--uavs {uavs})")
        if uav in out:
            raise ValueError(f"--autopilot uav{uav}: given twice ({out[uav]} and {endpoint})")
        key = endpoint.split(",")[0]
        if key in owner:
            raise ValueError(f"--autopilot uav{uav}: {key} is uav{owner[key]}'s already (one autopilot per link)")
        out[uav], owner[key] = endpoint, uav
    return dict(sorted(out.items()))
