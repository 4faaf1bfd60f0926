"""Edge states of a lazily opened map, read by HDF5 chunk with parallel decompression.

A map larger than memory keeps its states (q, qd, p: rows of float32) in the file.  The
planner reads a few hundred to a few thousand scattered edges per decision; through h5py
each of them costs a chunk decompressed under the interpreter lock, one after another
(about 6 s for 1,024 edges of a 5-million-edge map on an H100 host).  `StateReader` reads
the raw chunks (`read_direct_chunk`), undoes HDF5's deflate and shuffle filters on all
cores (zlib releases the lock) and keeps the decompressed chunks in a bounded LRU cache,
so the edges over a target, visited again at the next decision, cost nothing the second
time; a chunk stored with HDF5's Fletcher-32 checksum (maps lmjx writes) is checked as HDF5
would check it.  Datasets stored any other way (other filters or chunk shapes) are read
through h5py.  A damaged chunk, either way, is a one-line `MapFileError`.
"""

from __future__ import annotations

import threading
import zlib
from collections import OrderedDict
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor

import h5py
import numpy as np

from lmjx.errors import MapFileError
from lmjx.mapfile.checksum import ChecksumError, strip_checksum
from lmjx.runtime.cores import usable_cores

CACHE_BYTES = 256 * 2**20  # decompressed chunks kept per dataset


PLAIN = [h5py.h5z.FILTER_SHUFFLE, h5py.h5z.FILTER_DEFLATE]  # what lmjx writes, with or without Fletcher-32 last


def _plain_filters(ds: h5py.Dataset) -> bool:
    """True when every chunk of `ds` is shuffle, then deflate (what lmjx writes), then
    perhaps a Fletcher-32 checksum, nothing else."""
    if ds.chunks is None or ds.ndim != 2 or ds.chunks[1] != ds.shape[1] or ds.dtype != np.float32:
        return False
    if ds.compression != "gzip" or not ds.shuffle or ds.scaleoffset is not None:
        return False
    plist = ds.id.get_create_plist()
    names = [plist.get_filter(i)[0] for i in range(plist.get_nfilters())]
    return names in (PLAIN, [*PLAIN, h5py.h5z.FILTER_FLETCHER32])


def damaged(ds: h5py.Dataset, rows: str, why: str) -> MapFileError:
    """The one-line error for a damaged part of a map's dataset."""
    return MapFileError(
        f"{ds.file.filename}: {ds.name} is damaged ({rows}: {why}); lmjx info --verify lists every damaged part; "
        "rebuild the map"
    )


class StateReader:
    """Array-like view of an (S, w) float32 state dataset: `reader[a:b]`, `len(reader)`,
    `reader.shape`; `prefetch` decompresses the chunks of many row ranges at once."""

    def __init__(self, ds: h5py.Dataset, cache_bytes: int = CACHE_BYTES, threads: int | None = None) -> None:
        self.ds = ds
        self.shape = ds.shape
        self.dtype = ds.dtype
        self.fast = _plain_filters(ds)
        self.checked = bool(ds.fletcher32)  # chunks end in HDF5's Fletcher-32 checksum
        self.rows = ds.chunks[0] if ds.chunks else 0
        self.width = ds.shape[1] if ds.ndim == 2 else 0
        self.cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self.cache_bytes = cache_bytes
        self.held = 0
        self.threads = threads or usable_cores()
        self._pool: ThreadPoolExecutor | None = None
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return self.shape[0]

    @property
    def size(self) -> int:
        return self.ds.size

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def _decompress(self, c: int, raw: bytes) -> np.ndarray:
        """Chunk `c`'s rows from its stored bytes (checksum checked, deflate and shuffle undone)."""
        try:
            body = strip_checksum(raw) if self.checked else raw
            flat = np.frombuffer(zlib.decompress(body), np.uint8)
            # shuffle stores byte 0 of every element, then byte 1, ...: undo it
            return np.ascontiguousarray(flat.reshape(4, -1).T).view(np.float32).reshape(self.rows, self.width)
        except (ChecksumError, zlib.error, ValueError) as e:
            raise damaged(self.ds, f"rows {c * self.rows:,} to {(c + 1) * self.rows - 1:,}", str(e)) from None

    def _h5py_rows(self, key):
        """Rows read through h5py (which checks any checksum), a damaged chunk a MapFileError."""
        try:
            return self.ds[key]
        except OSError as e:
            raise damaged(self.ds, f"rows {key}", str(e).splitlines()[0] if str(e) else "unreadable") from None

    def _load(self, chunks: Iterable[int]) -> dict[int, np.ndarray]:
        """The chunks asked for, decompressing those not yet in the cache (all cores), then
        caching them.  The blocks are returned, not looked up again: caching the new ones may
        evict chunks of the same request (those already cached, the least recently used)."""
        want = list(dict.fromkeys(chunks))
        got: dict[int, np.ndarray] = {}
        for c in want:
            if c in self.cache:
                self.cache.move_to_end(c)
                got[c] = self.cache[c]
        todo = [c for c in want if c not in got]
        if not todo:
            return got
        raws = []
        for c in todo:
            try:
                mask, raw = self.ds.id.read_direct_chunk((c * self.rows, 0))
            except OSError as e:  # its place in the file is lost
                raise damaged(self.ds, f"the chunk of row {c * self.rows:,}", str(e).splitlines()[0]) from None
            if mask:  # a filter was skipped for this chunk: let HDF5 read it
                raws.append(None)
            else:
                raws.append(raw)
        if len(todo) > 1 and self.threads > 1:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="lmjx-states")
            blocks = list(self._pool.map(lambda c, r: None if r is None else self._decompress(c, r), todo, raws))
        else:
            blocks = [None if r is None else self._decompress(c, r) for c, r in zip(todo, raws, strict=True)]
        for c, block in zip(todo, blocks, strict=True):
            if block is None:
                a = c * self.rows
                block = np.zeros((self.rows, self.width), np.float32)
                part = self._h5py_rows(slice(a, min(a + self.rows, self.shape[0])))
                block[: len(part)] = part
            self._put(c, block)
            got[c] = block
        return got

    def _put(self, c: int, block: np.ndarray) -> None:
        self.cache[c] = block
        self.held += block.nbytes
        while self.held > self.cache_bytes and len(self.cache) > 1:
            _, old = self.cache.popitem(last=False)
            self.held -= old.nbytes

    def _chunks_of(self, a: int, b: int) -> range:
        return range(a // self.rows, (b - 1) // self.rows + 1) if b > a else range(0)

    def prefetch(self, ranges: Iterable[tuple[int, int]]) -> None:
        """Make rows [a, b) of every range cheap to read (their chunks decompressed at once)."""
        if not self.fast:
            return
        with self._lock:
            needed = [c for a, b in ranges for c in self._chunks_of(int(a), int(b))]
            # at most what the cache holds: beyond that, prefetching would evict its own chunks
            limit = max(1, self.cache_bytes // max(1, self.rows * self.width * 4))
            self._load(needed[:limit])

    def whole(self) -> np.ndarray:
        """Every row, in one array (the chunks decompressed on all cores, none kept in the cache)."""
        if not self.fast:
            return np.asarray(self._h5py_rows(slice(0, self.shape[0])))
        out = np.empty(self.shape, np.float32)
        n = -(-self.shape[0] // self.rows) if self.rows else 0

        def one(c: int) -> None:
            a = c * self.rows
            b = min(a + self.rows, self.shape[0])
            block = self.cache.get(c)
            if block is None:
                try:
                    mask, raw = self.ds.id.read_direct_chunk((a, 0))  # (h5py reads one at a time)
                except OSError as e:  # its place in the file is lost
                    raise damaged(self.ds, f"the chunk of row {a:,}", str(e).splitlines()[0]) from None
                block = self._decompress(c, raw) if not mask else None
            out[a:b] = block[: b - a] if block is not None else self._h5py_rows(slice(a, b))

        with self._lock:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="lmjx-states")
            list(self._pool.map(one, range(n)))
        return out

    def gather(self, rows: np.ndarray) -> np.ndarray:
        """Rows `rows` (any order, repeats allowed) as one (len(rows), w) array: every chunk
        they touch decompressed at once (all cores), each row copied once."""
        rows = np.asarray(rows, np.int64)
        if not len(rows):
            return np.zeros((0, self.width), self.dtype)
        if not self.fast:  # (HDF5's own selection: increasing rows, each once)
            unique, inverse = np.unique(rows, return_inverse=True)
            return np.asarray(self._h5py_rows(unique))[inverse]
        chunk = rows // self.rows
        order = np.argsort(chunk, kind="stable")
        bounds = np.flatnonzero(np.r_[True, chunk[order][1:] != chunk[order][:-1], True])
        out = np.empty((len(rows), self.width), np.float32)
        limit = max(1, self.cache_bytes // max(1, self.rows * self.width * 4) // 2)
        with self._lock:
            # at most half the cache at a time: a request never evicts its own chunks
            for g in range(0, len(bounds) - 1, limit):
                groups = range(g, min(g + limit, len(bounds) - 1))
                blocks = self._load(int(chunk[order[bounds[i]]]) for i in groups)
                for i in groups:
                    take = order[bounds[i] : bounds[i + 1]]
                    c = int(chunk[take[0]])
                    out[take] = blocks[c][rows[take] - c * self.rows]
        return out

    def __getitem__(self, key):
        if not self.fast or not isinstance(key, slice) or key.step not in (None, 1):
            return self._h5py_rows(key)
        a, b, _ = key.indices(self.shape[0])
        if b <= a:
            return np.zeros((0, self.width), np.float32)
        chunks = self._chunks_of(a, b)
        if len(chunks) * self.rows * self.width * 4 > self.cache_bytes // 2:
            return self._h5py_rows(key)  # a long run of rows: HDF5 reads it as well as we would
        with self._lock:
            blocks = self._load(chunks)
            parts = []
            for c in chunks:
                block = blocks[c]
                lo, hi = max(a, c * self.rows), min(b, (c + 1) * self.rows)
                parts.append(block[lo - c * self.rows : hi - c * self.rows])
            return np.concatenate(parts) if len(parts) > 1 else parts[0].copy()
