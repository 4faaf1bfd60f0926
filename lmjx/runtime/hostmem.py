"""Host memory: large buffers go back to the operating system when they are freed.

A streamed build (lmjx.edges.stream) allocates and frees hundreds of megabytes per chunk in
several threads.  glibc's allocator raises its mmap threshold as large blocks are freed
(up to 32 MB) and gives each thread its own arena, so those buffers end up in heaps that
are rarely returned: resident memory creeps up to a high-water mark well above what is in
use.  Fixing the threshold at 1 MB (blocks above it are mapped and unmapped) and capping the
arenas keeps resident memory near what the program holds.  A no-op where glibc is absent.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

M_ARENA_MAX = -8
M_MMAP_THRESHOLD = -3


def return_large_buffers(threshold: int = 1 << 20, arenas: int = 4) -> bool:
    """Set glibc's mmap threshold and arena cap for this process; True if it took effect."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, threshold)) and bool(mallopt(M_ARENA_MAX, arenas))
