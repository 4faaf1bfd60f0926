"""How lmjx opens HDF5 files: without HDF5's file locks.

lmjx writes every file atomically (a temporary file, renamed into place when complete), so
no reader ever sees a file being written, and the locks protect nothing.  They do harm: HDF5
locks a file with `flock` on a descriptor that processes started meanwhile inherit, and
XLA's GPU compiler starts processes (`ptxas`) while a build writes its files.  Such a child
holds the lock of a file the build has already closed, and the build's next open of it
fails ("unable to lock file", errno 11: measured on an H200 when a build's reach map was
written while the spatial index's programs compiled).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py


def h5open(path: str | Path, mode: str = "r", **kwargs: Any) -> h5py.File:
    """`h5py.File(path, mode, **kwargs)` without file locking."""
    return h5py.File(path, mode, locking=False, **kwargs)
