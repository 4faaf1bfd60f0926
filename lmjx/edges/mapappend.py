"""The map-writing process of a streamed build (`lmjx build-map`; `mapwriter` starts it and
feeds it): the saved chunks appended in order to the map being written, the spatial index
sorted from them at the end, then the closed map's content digest.

The digest (`mapfile.digest`) is computed without decompressing the map: its first datasets
in the digest's order, the edges' durations and the index's edge ids, are hashed as they are
written (the index on a thread of its own, beside its compression), and the edge states (most
of the map's bytes) from the chunk files, which hold them raw and stay in the partial folder
until the map is moved into place; the other datasets (small) are read from the closed map.
Where the closed map is not what that assumes (its datasets' names, dtypes, shapes, a chunk
file missing or of other rows), the digest is computed from the map as `content_digest` does.

It imports h5py, numpy and lmjx's map-file code only, never JAX or the robot's model
(`python -X importtime -c "import lmjx.edges.mapappend"`), so that it starts in a fraction
of a second: its job (`Job`) holds plain values.
"""

from __future__ import annotations

import collections
import contextlib
import itertools
import signal
import threading
import time
import traceback
from collections.abc import Callable, Generator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from multiprocessing.connection import Connection
from pathlib import Path

import h5py
import numpy as np

from lmjx.edges import chunkfile
from lmjx.mapfile.digest import Given, NotAsGivenError, RunningDigest, content_digest
from lmjx.mapfile.h5 import h5open
from lmjx.mapfile.schema import PER_EDGE, PER_STATE
from lmjx.mapfile.write import EdgeWriter, IndexGrid, write_index, write_rows
from lmjx.runtime import threadprof

INDEX_PAIRS = 64 * 2**20  # spatial-index pairs read from the chunk files at a time when assembling (512 MB)
PLACE_PAIRS = 4 * 2**20  # ... and placed at a time, on a thread of their own (16 MB of edge ids)
READ_AHEAD = 4  # chunk files the writing process reads ahead


@dataclass
class Job:
    """What the writing process is given (plain values: it imports neither JAX nor the robot)."""

    folder: Path
    nq: int
    n: int
    ranges: list[tuple[int, int]]  # every chunk of the map, in order
    saved: set[tuple[int, int]]  # those already saved by an earlier run
    threads: int
    tmp: Path  # the map being written (its head and /edges' settings written by the build's process)
    grid: IndexGrid  # the reach grid
    steps: int  # control steps per edge (the bundle's `steps`)
    reasons: tuple[str, ...]  # the rejection reasons a chunk counts, in order (`bundle.reasons`)
    appended: tuple[str, ...]  # the chunk arrays appended (the index pairs are read at the end)


def writer_process(inbox_fd: int, outbox_fd: int) -> None:
    """The writing process's entry point: its pipes from the build's process."""
    _writer_main(Connection(inbox_fd, writable=False), Connection(outbox_fd, readable=False))


def _writer_main(inbox: Connection, outbox: Connection) -> None:
    """The writing process: its job, then the map from the chunk files; the figures (or
    the error) back."""
    from lmjx.runtime.hostmem import return_large_buffers

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.current_thread().name = "lmjx-map-writer"
    return_large_buffers()  # as the build's process (lmjx.cli)
    try:
        job = inbox.recv()
    except (EOFError, OSError):  # the build's process stopped before it was sent whole
        return
    sampler = threadprof.from_environment()  # LMJX_THREAD_PROFILE: this process's threads too
    try:
        appender = _Appender(job, inbox)
        result = appender.run()
        if sampler is not None:
            result["threads"] = sampler.stop() | {"process": "writer"}
        outbox.send(("done", result, ""))
        # the closed map's content digest, while the build's process computes its push counts
        # (it adds both: the digest leaves the push counts out)
        t0 = time.perf_counter()
        digest, source = appender.digest()
        outbox.send(("digest", (digest, time.perf_counter() - t0, source), ""))
    except (EOFError, BrokenPipeError):
        return  # the build's process is gone
    except BaseException as e:
        trace = traceback.format_exc()
        try:
            outbox.send(("error", e, trace))
        except Exception:  # an exception that does not pickle, or the build's process is gone
            with contextlib.suppress(Exception):
                outbox.send(("error", RuntimeError(f"the map writer failed: {type(e).__name__}: {e}"), trace))


class _Appender:
    """The writing process's work: chunks appended in order as they are saved."""

    def __init__(self, job: Job, inbox) -> None:
        self.job, self.inbox = job, inbox
        self.ready: set[tuple[int, int]] = set()  # units the build's process says are saved
        # ("digest_index": hashing the index's edge ids for the digest, beside their writing)
        self.timing = {"waits": 0.0, "read": 0.0, "write_states": 0.0, "write_edges": 0.0, "index": 0.0,
                       "close": 0.0, "digest_index": 0.0}  # fmt: skip
        self.totals = {"counts": np.zeros(job.grid.nx * job.grid.ny, np.int64), "rejected": np.zeros(len(job.reasons),
                       np.int64), "rolled_out": 0, "evaluated": 0, "states": 0, "first_edge": []}  # fmt: skip
        self.file = h5open(job.tmp, "r+")  # its head written by the build's process
        self.w = EdgeWriter(self.file, None, None, job.nq, threads=job.threads)  # (its /edges made)
        # for the digest: each chunk's edge durations as /edges/duration holds them (4 bytes an
        # edge), each chunk's rows of every state array, the states' datasets' names
        self.durations: list[np.ndarray] = []
        self.state_rows: dict[str, list[int]] = {k: [] for k in PER_STATE}
        self.state_names = {k: self.w.columns[k].ds.name[1:] for k in PER_STATE}
        self.running: RunningDigest | None = None  # the digest's first datasets, fed as written

    def _next_unit(self) -> None:
        kind, *rest = self.inbox.recv()
        if kind != "unit":
            raise RuntimeError(f"the map writer got '{kind}' before every chunk")
        self.ready.add((rest[0], rest[1]))

    def _read(self, a: int, b: int) -> tuple[dict, dict]:
        t0 = time.perf_counter()
        arrays, head = chunkfile.read(self.job.folder, a, b, self.job.appended)
        self.timing["read"] += time.perf_counter() - t0  # summed over the readers
        return arrays, head

    def run(self) -> dict:
        job = self.job
        reader = ThreadPoolExecutor(READ_AHEAD, thread_name_prefix="lmjx-read")
        loads: collections.deque = collections.deque()  # reads in flight, in order
        k = 0  # the next range to read
        try:
            for _ in job.ranges:
                t0 = time.perf_counter()
                while k < len(job.ranges) and len(loads) < READ_AHEAD:
                    r = job.ranges[k]
                    # wait for a unit's message only when nothing else is being read
                    while r not in job.saved and r not in self.ready and (not loads or self.inbox.poll()):
                        self._next_unit()
                    if r not in job.saved and r not in self.ready:
                        break
                    loads.append(reader.submit(self._read, *r))
                    k += 1
                arrays, head = loads.popleft().result()
                self.timing["waits"] += time.perf_counter() - t0
                self._append(arrays, head)
        finally:
            reader.shutdown(cancel_futures=True)
        kind, attrs = self.inbox.recv()
        if kind != "finish":
            raise RuntimeError(f"the map writer got '{kind}' after the last chunk")
        return self._finish(attrs)

    def _append(self, c: dict, head: dict) -> None:
        t = self.totals
        t["first_edge"].append(self.w.n_edges)
        t0 = time.perf_counter()
        self.w.add_states(c["q"], c["qd"], c["p"])
        t1 = time.perf_counter()
        length = c["length"]
        starts = np.concatenate([[0], np.cumsum(length)[:-1]]).astype(np.int64)
        q_start = c["q"][starts] if len(length) else np.zeros((0, self.job.nq), np.float32)
        self.w.add_edges({name: q_start if name == "q_start" else c[name] for name in PER_EDGE})
        self.durations.append(np.array(c["duration"], self.w.columns["duration"].dtype))  # (a copy: as written)
        for k, rows in self.state_rows.items():
            rows.append(len(c[k]))
        t["counts"] += np.bincount(c["index_cell"], minlength=len(t["counts"]))
        t["rejected"] += c["rejected"]
        t["rolled_out"] += head["rolled_out"]
        t["evaluated"] += head["states_evaluated"]
        t["states"] += len(c["q"])
        self.timing["write_states"] += t1 - t0
        self.timing["write_edges"] += time.perf_counter() - t1

    def _finish(self, attrs: dict) -> dict:
        job, t = self.job, self.totals
        t0 = time.perf_counter()
        offset = np.zeros(len(t["counts"]) + 1, np.int64)
        offset[1:] = np.cumsum(t["counts"])
        ds = write_index(self.w.group, job.grid, offset, None)
        self.running = self._digest_head(ds)
        write_index_edges(ds, job.folder, job.ranges, t["first_edge"], offset,
                          self._hash_index if self.running is not None else None, job.threads)  # fmt: skip
        t1 = time.perf_counter()
        rejected = {r: int(k) for r, k in zip(job.reasons, t["rejected"], strict=True)}
        steps = t["rolled_out"] * job.steps
        sizes = self.w.close({"edges_sampled": job.n, "rejected": rejected, "edge_steps": steps,
                              "states_evaluated": t["evaluated"], **attrs})  # fmt: skip
        self.file.close()
        self.timing["index"] = t1 - t0
        self.timing["close"] = time.perf_counter() - t1
        return {"edges_sampled": job.n, "edges_valid": self.w.n_edges, "states": t["states"], "rejected": rejected,
                "edge_steps": steps, "states_evaluated": t["evaluated"], "timing": self.timing,
                "threads_used": job.threads, "peak_rss": peak_rss(), **sizes}  # fmt: skip

    def _digest_head(self, index: h5py.Dataset) -> RunningDigest | None:
        """The digest begun with the datasets that sort before the others: the edges'
        durations (kept as appended), then the index's edge ids' head (their rows follow as
        they are written).  None where the map has no durations (no chunk appended)."""
        col = self.w.columns.get("duration")
        if col is None:
            return None
        durations = np.concatenate(self.durations) if self.durations else np.zeros(0, col.dtype)
        self.durations = []
        running = RunningDigest()
        running.begin(col.ds.name[1:], col.dtype, durations.shape)
        running.update(durations)
        running.begin(index.name[1:], index.dtype, index.shape)
        return running

    def _hash_index(self, edges: np.ndarray) -> None:
        t0 = time.perf_counter()
        self.running.update(edges)
        self.timing["digest_index"] += time.perf_counter() - t0

    def digest(self) -> tuple[str, str]:
        """The closed map's content digest, and where its states were read: "chunk files" (the
        states hashed from the chunk files, which hold them raw, instead of decompressing the
        map; the durations and the index fed as they were written) or "map" (the map is not
        what that assumes, or a chunk file is gone: `content_digest`, from the map alone)."""
        if self.running is not None:
            given = {self.state_names[k]: Given(np.dtype(np.float32), (sum(rows), self.w.widths[k]),
                                                partial(self._chunk_states, k))
                     for k, rows in self.state_rows.items()}  # fmt: skip
            try:
                value = self.running.finish(self.job.tmp, given)
            except chunkfile.ChunkFileError:
                value = None
            if value is not None:
                return value, "chunk files"
        return content_digest(self.job.tmp)[0], "map"

    def _chunk_states(self, name: str) -> Generator[np.ndarray, None, None]:
        """State array `name` (q, qd or p) of every chunk, in order, as `add_states` appended it
        (as float32), READ_AHEAD chunks read ahead on threads (reading and hashing release the
        interpreter lock: they overlap); `NotAsGivenError` where a chunk's rows are not those appended."""
        job = self.job
        pool = ThreadPoolExecutor(READ_AHEAD, thread_name_prefix="lmjx-digest-read")
        reads = (pool.submit(chunkfile.read, job.folder, a, b, (name,)) for a, b in job.ranges)
        window = collections.deque(itertools.islice(reads, READ_AHEAD))
        try:
            for rows in self.state_rows[name]:
                arrays, _ = window.popleft().result()
                window.extend(itertools.islice(reads, 1))
                block = np.asarray(arrays[name], np.float32)
                if len(block) != rows:
                    raise NotAsGivenError(f"{name}: {len(block)} rows in a chunk file, {rows} appended")
                yield block
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def peak_rss() -> int:
    """This process's peak resident memory in bytes: VmHWM, which a new program starts
    afresh (getrusage's ru_maxrss keeps, across exec, what the forking process held)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def write_index_edges(
    ds: h5py.Dataset,
    folder: Path,
    ranges: list[tuple[int, int]],
    first_edge: list[int],
    offset: np.ndarray,
    hash_out: Callable[[np.ndarray], None] | None = None,
    threads: int = 1,
) -> None:
    """The index's edge ids, sorted by cell then edge, a range of cells at a time (each
    range at most INDEX_PAIRS pairs, read from every saved chunk).  Each chunk's pairs are
    sorted by (cell, edge) and the chunks come in edge order, so every pair's place is
    known without sorting: its cell's start (`offset`), plus the pairs earlier chunks put
    there, plus its rank among its chunk's pairs of that cell.  The chunks of a range are
    read and placed on `threads` threads (file reads, checksums and numpy's gathers and
    scatters leave the interpreter lock: one thread placed a 5,000,000-edge map's 128 M ids
    in about 3.4 s of the build's end), compressed and written on as many (`write_rows`);
    `hash_out`: given each range's ids in order, on a thread of its own meanwhile."""
    with ThreadPoolExecutor(1, thread_name_prefix="lmjx-digest") as hasher, \
            ThreadPoolExecutor(threads, thread_name_prefix="lmjx-index") as pool:  # fmt: skip
        hashing: list = []

        def ranges_out():
            for out in _index_ranges(folder, ranges, first_edge, offset, pool):
                if hash_out is not None:
                    if hashing:
                        hashing.pop().result()  # (one range's ids held for it at a time)
                    hashing.append(hasher.submit(hash_out, out))
                yield out

        write_rows(ds, ranges_out(), threads)
        if hashing:
            hashing.pop().result()


def _index_ranges(
    folder: Path, ranges: list[tuple[int, int]], first_edge: list[int], offset: np.ndarray, pool: ThreadPoolExecutor
) -> Generator[np.ndarray, None, None]:
    """The edge ids of each range of cells with pairs, in order (`write_index_edges`): the
    chunks' pairs of a range read once, on `pool`, then placed on `pool` in parts of at most
    PLACE_PAIRS pairs (a part's ids stay in the processor's caches while they are scattered)."""
    if len(ranges) != len(first_edge):
        raise ValueError(f"{len(ranges)} chunks but {len(first_edge)} first edges")
    n_cells = len(offset) - 1
    for c0, c1 in _cell_ranges(offset, 0, n_cells, INDEX_PAIRS):
        pieces = [p for p in pool.map(partial(_range_piece, folder, c0, c1), ranges, first_edge) if p is not None]
        parts = _cell_ranges(offset, c0, c1, PLACE_PAIRS)
        for out in pool.map(partial(_place, offset, c0, pieces), parts):
            if len(out):
                yield out
        del pieces  # (before the next range's are read)


def _cell_ranges(offset: np.ndarray, c0: int, c1: int, pairs: int) -> list[tuple[int, int]]:
    """Cells [c0, c1) cut into consecutive ranges of at most `pairs` pairs (or one cell of more)."""
    out = []
    while c0 < c1:
        c = max(c0 + 1, int(np.searchsorted(offset, offset[c0] + pairs, side="right")) - 1)
        out.append((c0, min(c, c1)))
        c0 = out[-1][1]
    return out


def _range_piece(folder: Path, c0: int, c1: int, rng: tuple[int, int], e0: int) -> tuple[np.ndarray, np.ndarray] | None:
    """A chunk's pairs with cells in [c0, c1): (cells - c0, edge ids in the map), sorted by
    cell as the chunk's pairs are; None where it has none."""
    pairs, _ = chunkfile.read(folder, rng[0], rng[1], ("index_cell", "index_edge"))
    cell, edge = pairs["index_cell"], pairs["index_edge"]
    lo, hi = np.searchsorted(cell, [c0, c1])
    if hi == lo:
        return None
    return cell[lo:hi] - np.int32(c0), edge[lo:hi] + np.int32(e0)


def _place(offset: np.ndarray, c0: int, pieces: list[tuple], part: tuple[int, int]) -> np.ndarray:
    """The edge ids of cells `part` (within the range from `c0` whose chunks' `pieces` are
    given, in edge order): each pair at its cell's start, plus the pairs earlier chunks put
    there, plus its rank among its chunk's pairs of that cell."""
    a, b = part[0] - c0, part[1] - c0
    out = np.empty(int(offset[part[1]] - offset[part[0]]), np.int32)
    fill = (offset[part[0] : part[1]] - offset[part[0]]).astype(np.int64)  # each cell's next free place in `out`
    ends = offset[part[0] + 1 : part[1] + 1] - offset[part[0]]  # ... and where it ends
    cells = np.arange(b - a + 1, dtype=np.int32)
    miscounted = f"the chunk files hold other index pairs than those counted (cells {part[0]}-{part[1]})"
    for c, edges in pieces:
        lo, hi = np.searchsorted(c, [a, b])
        if hi == lo:
            continue
        cc = c[lo:hi] - np.int32(a)
        bounds = np.searchsorted(cc, cells)  # where each cell's pairs begin among the chunk's
        count = np.diff(bounds)
        if np.any(fill + count > ends):  # (before they are placed: past their cells' room)
            raise RuntimeError(miscounted)
        out[fill[cc] + (np.arange(hi - lo) - bounds[cc])] = edges[lo:hi]
        fill += count
    if not np.array_equal(fill, ends):
        raise RuntimeError(miscounted)
    return out
