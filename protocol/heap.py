"""Handing freed heap back to the system (glibc ``malloc_trim(3)``): no Zenoh needed."""

from __future__ import annotations

import contextlib
import ctypes
import time

__all__ = ["release_freed_memory", "resident_mb", "settled_resident_mb"]


def release_freed_memory() -> None:
    """Return the free pages of every malloc arena to the system (``malloc_trim(0)``); a no-op without glibc.

    Freed memory otherwise stays in the process for later allocations: the synthetic wall's start-up
    temporaries in every edge (~24 MB), a departed session's declarations in the gateway."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").malloc_trim(0)


def resident_mb(pid: int) -> float:
    """A process's resident memory (``VmRSS`` of ``/proc/PID/status``, proc(5)), MB."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise ValueError(f"no VmRSS for process {pid}")


def settled_resident_mb(pid: int, within_s: float = 15.0) -> float:
    """:func:`resident_mb` once two readings a second apart agree within 0.2 MB (or after ``within_s``)."""
    last, end = resident_mb(pid), time.monotonic() + within_s
    while time.monotonic() < end:
        time.sleep(1.0)
        now = resident_mb(pid)
        if abs(now - last) < 0.2:
            return now
        last = now
    return last
