"""A map's content digest: SHA-256 over every dataset of its content (name, dtype, shape,
bytes, in the order of their names): the robot, the reach map, the edges and their index.

Left out: every attribute (a build's timings and device differ between builds of the same
map, and the digest itself is stored as one) and the groups derived from the content
(`DERIVED`: the push counts, computed from the edges on the build's platform), so that a
map's digest is that of its content whichever lmjx version or platform added those.  Two
builds with the same command and seed hold the same map when their digests agree.

The build stores the digest of what it wrote as the root attribute `content_digest`
(`store_digest`), so that an evaluation names its maps without reading them again
(`map_digest`: the stored one where present, else computed).  Nothing here writes a map's
datasets.  The edge states (most of a map's bytes) are read by HDF5 chunk and decompressed
on all cores (`lazystates.StateReader`): the same bytes as h5py's, several times faster.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import h5py
import numpy as np

from lmjx.mapfile.h5 import h5open

ROWS = 1 << 20  # rows read at a time
DERIVED = ("edges/push",)  # groups derived from the content: not hashed
DIGEST_ATTR = "content_digest"  # the root attribute the build stores the digest in


def _bytes(a: np.ndarray) -> bytes:
    """An array's content; strings and other objects by value (their buffer holds pointers)."""
    if a.dtype.kind != "O":
        return np.ascontiguousarray(a).tobytes()
    return b"\0".join(x if isinstance(x, bytes) else repr(x).encode() for x in a.ravel())


def hashed(name: str) -> bool:
    """Whether the dataset `name` (a path inside the file, no leading '/') is content."""
    return not any(name == d or name.startswith(d + "/") for d in DERIVED)


def content_digest(path: str | Path, each: dict[str, str] | None = None, parallel: bool = True) -> tuple[str, int]:
    """(hex digest, datasets hashed) of the map at `path`; `each` gets every dataset's own
    (its first 16 hex digits).  `parallel`: datasets stored as lmjx stores edge states
    decompressed on all cores (else every dataset through h5py: the same digest)."""
    h, names = hashlib.sha256(), []
    with h5open(path, "r") as f:
        f.visititems(lambda name, obj: names.append(name) if isinstance(obj, h5py.Dataset) else None)
        for name in sorted(n for n in names if hashed(n)):
            ds = f[name]
            h.update(f"{name}|{ds.dtype.str}|{ds.shape}".encode())
            rows = [ds[()]] if not ds.shape else _blocks(ds, parallel)
            one = hashlib.sha256()
            for block in rows:
                b = _bytes(np.asarray(block))
                h.update(b)
                one.update(b)
            if each is not None:
                each[name] = one.hexdigest()[:16]
        count = sum(1 for n in names if hashed(n))
    return h.hexdigest(), count


def _blocks(ds: h5py.Dataset, parallel: bool):
    """`ds`'s rows, ROWS at a time, in order."""
    from lmjx.mapfile.lazystates import StateReader

    reader = StateReader(ds) if parallel else None
    if reader is None or not reader.fast:  # (not stored as lmjx stores states: through h5py)
        yield from (ds[i : i + ROWS] for i in range(0, ds.shape[0], ROWS))
        return
    # room for a block's chunks (whole chunks: a block may start and end inside one), twice
    reader.cache_bytes = 2 * (ROWS + 2 * reader.rows) * reader.width * ds.dtype.itemsize
    try:
        n = ds.shape[0]
        for i in range(0, n, ROWS):
            reader.prefetch([(i, min(i + ROWS, n))])  # (its chunks decompressed at once, on all cores)
            yield reader[i : min(i + ROWS, n)]
    finally:
        reader.close()


def stored_digest(path: str | Path) -> str | None:
    """The digest the build stored in the map at `path`, or None (a map written without it)."""
    with h5open(path, "r") as f:
        value = f.attrs.get(DIGEST_ATTR)
    if value is None:
        return None
    return value.decode() if isinstance(value, bytes) else str(value)


def store_digest(path: str | Path) -> str:
    """Compute the content digest of the map at `path` (complete, closed) and store it as its
    root attribute `content_digest`; the digest back.  The writers call it on their
    temporary file, before it is renamed into place."""
    digest, _ = content_digest(path)
    with h5open(path, "r+") as f:
        f.attrs[DIGEST_ATTR] = digest
    return digest


def map_digest(path: str | Path) -> tuple[str, str]:
    """(digest, where it came from) of the map at `path`: "stored" (the build's attribute)
    or "computed" (read here: a map written without the attribute)."""
    stored = stored_digest(path)
    if stored is not None:
        return stored, "stored"
    return content_digest(path)[0], "computed"
