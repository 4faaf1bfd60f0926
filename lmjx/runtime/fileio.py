"""Atomic file writing and output-path checks.

Every file lmjx writes for users goes through `atomic_path`: the content is written to a
temporary file beside the destination and renamed over it only when complete, so an
interrupted run (Ctrl-C, crash) never leaves a partial file at the destination.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from lmjx.errors import OutputPathError


def check_writable(path: str | Path, what: str = "output") -> Path:
    """Fail early, with a clear message, if `path` cannot be written; create missing parents."""
    p = Path(path)
    if str(path).strip() == "":
        raise OutputPathError(f"{what} path is empty")
    if p.exists() and p.is_dir():
        raise OutputPathError(f"{what} path {p} is a directory; give a file name")
    parent = p.parent if str(p.parent) else Path(".")
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputPathError(f"cannot create the folder {parent} for the {what}: {e.strerror}") from None
    if not parent.is_dir():
        raise OutputPathError(f"cannot write the {what} to {p}: {parent} is not a folder")
    try:
        fd, probe = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".probe", dir=parent)
    except OSError as e:
        raise OutputPathError(f"cannot write the {what} to {p}: {e.strerror}") from None
    os.close(fd)
    os.unlink(probe)
    if p.exists() and not os.access(p, os.W_OK):
        raise OutputPathError(f"cannot overwrite the {what} {p}: permission denied")
    return p


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[str]:
    """Yield a temporary path beside `path`; on success rename it to `path`, else delete it."""
    dest = Path(path)
    parent = dest.parent if str(dest.parent) else Path(".")
    parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=".tmp", dir=parent)
    os.close(fd)
    try:
        yield tmp
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, dest)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_text_atomic(path: str | Path, text: str) -> None:
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as f:
        f.write(text)
