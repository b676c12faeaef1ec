"""Give freed heap memory back to the operating system between the phases of a long run.

A SLAM run allocates and frees many mid-sized arrays (submap grids, match fields, max-grids);
glibc keeps the freed pages in its heap, so the process's resident size stays at its
high-water mark while the next phase (the final map) allocates more. ``malloc_trim(0)``
returns those pages. Elsewhere (macOS, Windows, musl) this is a no-op.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

__all__ = ["release_freed_memory"]

_trim = None
if sys.platform.startswith("linux"):
    try:  # pragma: no branch - depends on the C library
        _libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        _trim = getattr(_libc, "malloc_trim", None)
    except OSError:  # pragma: no cover - no loadable C library
        _trim = None


def release_freed_memory() -> bool:
    """Return freed heap pages to the OS (glibc's ``malloc_trim``); whether it was done."""
    if _trim is None:
        return False
    return bool(_trim(0)) or True
