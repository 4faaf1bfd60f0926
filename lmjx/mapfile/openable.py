"""A map file's path checked before anything heavy is imported: a command given a path that
does not exist, a folder or a file that is not HDF5 says so in one line at once (`load_map`
checks the same, and then the file's content)."""

from __future__ import annotations

from pathlib import Path

from lmjx.errors import MapFileError

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"  # at byte 0, 512, 1024, 2048, ... (after a user block)


def check_map_path(path: str | Path) -> Path:
    """`path` as a Path when it names a readable HDF5 file; else a one-line MapFileError."""
    p = Path(path)
    if not p.exists():
        raise MapFileError(f"map file {p} does not exist")
    if p.is_dir():
        raise MapFileError(f"{p} is a folder, not a map file")
    try:
        with open(p, "rb") as f:
            size = p.stat().st_size
            at = 0
            while at + len(HDF5_SIGNATURE) <= size:
                f.seek(at)
                if f.read(len(HDF5_SIGNATURE)) == HDF5_SIGNATURE:
                    return p
                at = 512 if at == 0 else 2 * at
    except OSError as e:
        raise MapFileError(f"cannot read {p}: {e}") from None
    raise MapFileError(f"{p} is not an HDF5 file (an lmjx map is HDF5)")
