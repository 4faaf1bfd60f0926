"""How lmjx opens HDF5 files: those it writes without HDF5's file locks.

lmjx writes every file atomically (a temporary file, renamed into place when complete), so
no reader ever sees a file being written, and a lock on the file being written protects
nothing.  It does harm: HDF5 locks a file with `flock` on a descriptor that processes
started meanwhile inherit, and XLA's GPU compiler starts processes (`ptxas`) while a build
writes its files.  Such a child holds the lock of a file the build has already closed, and
the build's next open of it fails ("unable to lock file", errno 11: seen on an H200 when a
build's reach map was written while the spatial index's programs compiled).  Files opened
to read keep HDF5's locks: a reader's shared lock never stops another reader, and a file a
user holds open elsewhere in the same process must be opened with the same locking (HDF5:
"file locking flag values don't match").
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py


def h5open(path: str | Path, mode: str = "r", **kwargs: Any) -> h5py.File:
    """`h5py.File(path, mode, **kwargs)`; opened to write ("w", "r+", "a", ...) without file locking."""
    if mode != "r":
        kwargs.setdefault("locking", False)
    return h5py.File(path, mode, **kwargs)
