"""One compilation of a program per machine: processes that need the same program at once
(`lmjx evaluate --processes`, builds side by side, a test run's workers) take turns, so that
the first compiles it into the persistent compile cache and the others load it from there
instead of compiling it again each.

`compiling(ident)` holds an exclusive lock on a file named for the program in the lmjx
cache folder (`locks/`) while its holder lowers and compiles it.  The operating system lets the
lock go when its process ends however it ends, so a killed process never blocks the others.
Without a cache folder, where the folder cannot be written, or without POSIX file locks, it
holds nothing: every process compiles for itself, as without it.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

try:
    import fcntl
except ImportError:  # (not a POSIX system: no locks)
    fcntl = None  # type: ignore[assignment]


@contextlib.contextmanager
def compiling(ident: str) -> Iterator[None]:
    """Within: this process alone on this machine compiles the program named `ident` (a
    file name's worth of hex: `lmjx.runtime.batching.program_ident`)."""
    from lmjx.runtime.cache import cache_dir

    folder = cache_dir()
    if folder is None:
        yield
        return
    with contextlib.suppress(OSError):  # (mkdir: a folder this process cannot write: no lock)
        (folder / "locks").mkdir(parents=True, exist_ok=True)
    with held(folder / "locks" / f"{ident[:32]}.lock"):
        yield


@contextlib.contextmanager
def held(path: Path) -> Iterator[None]:
    """Within: this process alone holds the lock file `path` (an exclusive POSIX lock, let go
    when the process ends however it ends); where the file cannot be made or locked, or the
    system has no such locks, nothing is held."""
    if fcntl is None:
        yield
        return
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:  # a folder this process cannot write: no lock
        yield
        return
    try:
        with contextlib.suppress(OSError):  # a file system without locks: no lock
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # (lets the lock go)
