"""A process tells whoever started it that it is up: one line on an inherited pipe, as systemd's
``sd_notify(READY=1)`` does on its socket.

Design notes: docs/bus.md (protocol/readiness.py).
"""

from __future__ import annotations

import logging
import os
import re
import stat

log = logging.getLogger("skynet.readiness")

#: the environment variable holding the ready pipe's write end (a descriptor number >= 3)
READY_FD_ENV = "SKYNET_READY_FD"
#: the longest ready line a launcher reads, bytes
MAX_LINE = 256
_TOKEN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


def ready_line(role: str, name: str) -> bytes:
    """``ready <role> <name>\\n``; ValueError for a role or name that is not one short token."""
    for what, value in (("role", role), ("name", name)):
        if not isinstance(value, str) or not _TOKEN.fullmatch(value):
            raise ValueError(f"ready signal: {what} {value!r} is not a short token")
    return f"ready {role} {name}\n".encode()


def parse_ready(data: bytes) -> tuple[str, str] | None:
    """``(role, name)`` of a ready line, None for anything else (too long, not ASCII, wrong shape).

    >>> parse_ready(b"ready edge uav2\\n")
    ('edge', 'uav2')
    >>> parse_ready(b"ready edge") is None
    True
    """
    if len(data) > MAX_LINE or not data.endswith(b"\n"):
        return None
    try:
        words = data[:-1].decode("ascii").split(" ")
    except UnicodeDecodeError:
        return None
    if len(words) != 3 or words[0] != "ready" or not all(_TOKEN.fullmatch(w) for w in words[1:]):
        return None
    return words[1], words[2]


def notify_ready(role: str, name: str | None = None) -> bool:
    """Tell the launcher this process is up (docs/bus.md); True when the line was written."""
    value = os.environ.pop(READY_FD_ENV, None)
    if value is None:
        return False
    try:
        line = ready_line(role, name or role)
        fd = int(value)
        if fd < 3:
            raise ValueError(f"descriptor {fd} is a standard stream")
        st = os.fstat(fd)
        if not stat.S_ISFIFO(st.st_mode):
            raise ValueError(f"descriptor {fd} is not a pipe")
        try:
            os.write(fd, line)
        finally:
            os.close(fd)
    except (ValueError, OSError) as exc:
        log.warning("ready signal not sent (%s=%.20r): %s", READY_FD_ENV, value, exc)
        return False
    return True
