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

A writer that holds most of the bytes itself computes the same digest without reading them
back (`RunningDigest`): the first datasets fed as it writes them, the closed map's others
hashed from blocks it gives (`Given`) or read from the file, each checked against the
file's names, dtypes and shapes; where anything differs it gets None and computes
`content_digest`, so that the stored digest is always `content_digest`'s.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Generator
from dataclasses import dataclass
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


def _head(name: str, dtype: np.dtype, shape: tuple[int, ...]) -> bytes:
    """What the digest takes before a dataset's bytes: its name, dtype and shape."""
    return f"{name}|{dtype.str}|{shape}".encode()


def _hashed_names(f: h5py.File) -> list[str]:
    """The content datasets of an open map, in the order they are hashed (their names')."""
    names: list[str] = []
    f.visititems(lambda name, obj: names.append(name) if isinstance(obj, h5py.Dataset) else None)
    return sorted(n for n in names if hashed(n))


def content_digest(path: str | Path, each: dict[str, str] | None = None, parallel: bool = True) -> tuple[str, int]:
    """(hex digest, datasets hashed) of the map at `path`; `each` gets every dataset's own
    (its first 16 hex digits).  `parallel`: datasets stored as lmjx stores edge states
    decompressed on all cores (else every dataset through h5py: the same digest)."""
    h = hashlib.sha256()
    with h5open(path, "r") as f:
        names = _hashed_names(f)
        for name in names:
            ds = f[name]
            h.update(_head(name, ds.dtype, ds.shape))
            one = hashlib.sha256()
            for block in _blocks(ds, parallel):
                b = _bytes(np.asarray(block))
                h.update(b)
                one.update(b)
            if each is not None:
                each[name] = one.hexdigest()[:16]
    return h.hexdigest(), len(names)


def _blocks(ds: h5py.Dataset, parallel: bool):
    """`ds`'s rows, ROWS at a time, in order (a scalar dataset: its value)."""
    from lmjx.mapfile.lazystates import StateReader

    if not ds.shape:
        yield ds[()]
        return
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


def _raw(a: np.ndarray) -> np.ndarray:
    """An array's bytes as a flat view where it is contiguous (what `_bytes` gives for numbers, uncopied)."""
    return np.ascontiguousarray(a).reshape(-1).view(np.uint8)


def _size(ds: h5py.Dataset) -> int:
    """Bytes of a dataset's content, as numbers."""
    return int(np.prod(ds.shape, dtype=np.int64)) * ds.dtype.itemsize


class NotAsGivenError(Exception):
    """A writer's bytes are not what the map holds (raised by a `Given`'s blocks): the digest
    is then computed from the map."""


@dataclass(frozen=True)
class Given:
    """A dataset's content as its writer has it: the dtype and shape the map must hold, and
    its rows block by block, in order (`blocks()`, which may raise `NotAsGivenError`)."""

    dtype: np.dtype
    shape: tuple[int, ...]
    blocks: Callable[[], Generator[np.ndarray, None, None]]


class RunningDigest:
    """`content_digest` of a map computed from bytes its writer has: the datasets that sort
    first fed while the map is written (`begin`, then `update` with their rows in order),
    then, the map closed, the rest (`finish`): those `Given` hashed from the writer's blocks,
    the others read from the file.  `finish` checks every assumption against the closed
    file (its datasets' names and order, dtypes and shapes, the bytes fed for each) and
    gives None where one fails: the caller then computes `content_digest`.  `update` may be
    called from another thread than `begin`'s, one call at a time."""

    def __init__(self) -> None:
        self.h = hashlib.sha256()
        self.fed: list[list] = []  # [name, head, dtype, trailing shape, bytes fed]
        self.ok = True  # every block fed had its dataset's dtype and row shape

    def begin(self, name: str, dtype: np.dtype, shape: tuple[int, ...]) -> None:
        """The next dataset (`name` as `content_digest` names it): its dtype and shape as the map will hold them."""
        dtype, shape = np.dtype(dtype), tuple(int(n) for n in shape)
        head = _head(name, dtype, shape)
        self.ok = self.ok and dtype.kind != "O"  # (objects are hashed by value: only numbers fed)
        self.h.update(head)
        self.fed.append([name, head, dtype, shape[1:], 0])

    def update(self, rows: np.ndarray) -> None:
        """The next rows of the dataset begun last."""
        entry = self.fed[-1]
        if rows.dtype != entry[2] or rows.shape[1:] != entry[3]:
            self.ok = False
            return
        self.h.update(_raw(rows))
        entry[4] += rows.nbytes

    def finish(self, path: str | Path, given: dict[str, Given], parallel: bool = True) -> str | None:
        """The digest of the closed map at `path`, or None where it does not hold what was fed
        and given.  `parallel`: as `content_digest`'s, for the datasets read from the file."""
        if not self.ok:
            return None
        h = self.h.copy()
        with h5open(path, "r") as f:
            names = _hashed_names(f)
            fed = [entry[0] for entry in self.fed]
            if names[: len(fed)] != fed or not set(given) <= set(names[len(fed) :]):
                return None
            for name, head, _, _, nbytes in self.fed:
                ds = f[name]
                if _head(name, ds.dtype, ds.shape) != head or nbytes != _size(ds):
                    return None
            for name in names[len(fed) :]:
                ds, g = f[name], given.get(name)
                if g is not None and (np.dtype(g.dtype).str != ds.dtype.str or tuple(g.shape) != ds.shape):
                    return None  # (checked before its bytes: the rows add up to the dataset's)
                h.update(_head(name, ds.dtype, ds.shape))
                if g is None:
                    for block in _blocks(ds, parallel):
                        h.update(_bytes(np.asarray(block)))
                    continue
                nbytes, blocks = 0, g.blocks()
                try:
                    for block in blocks:
                        if block.dtype != ds.dtype or block.shape[1:] != ds.shape[1:]:
                            return None
                        h.update(_raw(block))
                        nbytes += block.nbytes
                except NotAsGivenError:
                    return None
                finally:
                    blocks.close()  # (its reads ahead stopped where it was left early)
                if nbytes != _size(ds):
                    return None
        return h.hexdigest()


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
