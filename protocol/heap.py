"""Handing freed heap back to the system (glibc ``malloc_trim(3)``): no Zenoh needed."""

from __future__ import annotations

import contextlib
import ctypes

__all__ = ["release_freed_memory"]


def release_freed_memory() -> None:
    """Return the free pages of every malloc arena to the system (``malloc_trim(0)``); a no-op without glibc.

    Freed memory otherwise stays in the process for later allocations: the synthetic wall's start-up
    temporaries in every edge (~24 MB), a departed session's declarations in the gateway."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").malloc_trim(0)
