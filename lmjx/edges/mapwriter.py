"""The map writing of a streamed build (`lmjx build-map`): packing computed chunks into the
partial folder, and a process of its own appending them to the HDF5 map.

In the build's process, `packer_threads()` threads pack each computed chunk's valid edges
with their spatial-index entries (`bundle.pack_chunk`) and save them to the partial folder
(`chunkfile`); a feeder thread tells the writing process, in edge order, which are saved.

The writing process (`writer_process`: a clean interpreter, with its own interpreter
lock) reads the chunk files ahead on a few threads, appends them in order to
`<partial>/map-<pid>.h5.tmp` with `mapfile.EdgeWriter` (compression and chunk writes on its own
threads), and at the end sorts the spatial index from the chunk files.  Measured on 2 H200s
(benchmarks/RESULTS.md): in the build's process, beside some 45 busy threads, the
HDF5 writes waited on the interpreter lock and on h5py's lock in turn, and the map writer
set a 2-GPU build's pace; in a process of its own they do not compete with the rollouts'
host work.

The process runs in a session of its own, so Ctrl-C reaches only the build, which stops it;
it ends when the build's process dies (its pipe closes); a rerun deletes the map it was
writing.
"""

from __future__ import annotations

import collections
import contextlib
import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
import time
import traceback
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path

import h5py
import numpy as np

from lmjx.edges import chunkfile
from lmjx.edges.bundle import BundleConfig, reasons
from lmjx.edges.chunk import EdgeChunk, chunk_ranges, pack_chunk
from lmjx.edges.sampling import split_rolled
from lmjx.errors import LmjxError
from lmjx.mapfile.digest import store_digest
from lmjx.mapfile.schema import PER_EDGE
from lmjx.mapfile.write import EdgeWriter, store_push_counts, write_head, write_index
from lmjx.model.robot import Robot
from lmjx.reach.reachability import ReachResult
from lmjx.runtime import threadprof
from lmjx.runtime.cores import usable_cores

# Sampled edges packed (and saved to the partial folder) at a time; not part of the result
# (LMJX_PACK_EDGES overrides it: the tests use small units).
PACK_EDGES = int(os.environ.get("LMJX_PACK_EDGES", 1 << 16))
INDEX_PAIRS = 64 * 2**20  # spatial-index pairs placed at a time when assembling (256 MB of edge ids)
READ_AHEAD = 4  # chunk files the writing process reads ahead
# the chunk arrays the writing process appends (the index pairs are read at the end)
APPENDED = tuple(k for k in EdgeChunk.ARRAYS if k != "index_edge")


def packer_threads() -> int:
    """Threads packing computed chunks: a third of the cores this process may use, 1 to 12."""
    return max(1, min(12, usable_cores() // 3))


def writer_threads() -> int:
    """Threads compressing and writing the map in the writing process: up to 8 (the
    compression of a 2-GPU build's states needs about 2 cores)."""
    return max(1, min(8, usable_cores()))


@dataclass
class _Job:
    """What the writing process is given."""

    folder: Path
    reach: ReachResult
    config: BundleConfig
    nq: int
    n: int
    ranges: list[tuple[int, int]]  # every chunk of the map, in order
    saved: set[tuple[int, int]]  # those already saved by an earlier run
    threads: int
    tmp: Path  # the map being written


class MapWriter:
    """The build process's side: `put` hands over computed chunks (blocking while, per
    device, a chunk's packing units and 4 more are waiting to be packed), `finish` waits for the
    map and moves it to `out`, `abort` stops the writing process."""

    def __init__(
        self,
        folder: Path,
        reach: ReachResult,
        config: BundleConfig,
        robot: Robot,
        n: int,
        done: list[tuple[int, int]],
        todo: list[tuple[int, int]],
        devices: int = 1,
    ) -> None:
        self.folder, self.reach, self.config, self.robot = folder, reach, config, robot
        units = [u for a, b in todo for u in chunk_ranges(b, PACK_EDGES, a)]
        self.n_units = len(units)
        # the map being written: a name of this run's own (a writing process a killed run left
        # behind, until it notices, keeps writing its own file, unlinked here)
        for old in folder.glob("map*.h5.tmp"):
            old.unlink(missing_ok=True)
        self.tmp = folder / f"map-{os.getpid()}.h5.tmp"
        self.packers = packer_threads()
        self.pool = ThreadPoolExecutor(self.packers, thread_name_prefix="lmjx-pack")
        most = max((b - a for a, b in todo), default=1)
        # pack jobs, in order: per device, a chunk's units and 4 more (on 2 H200s, 6 in all
        # kept the packers from keeping up: benchmarks/RESULTS.md)
        self.queue: queue.Queue = queue.Queue(maxsize=devices * (-(-most // PACK_EDGES) + 4))
        self.error: BaseException | None = None  # what stopped the packers or the feeder
        self.stop = threading.Event()  # the feeder's stop (abort)
        self.threads_report: dict | None = None  # the writing process's LMJX_THREAD_PROFILE report
        self.t_wait = 0.0
        # packers' seconds (summed), the final wait, the content digest (`mapfile.digest`), moving the map
        # to `out`, removing the partial folder (and "push": the push counts' seconds)
        self.parts = {"pack": 0.0, "save": 0.0, "drain": 0.0, "digest": 0.0, "replace": 0.0, "remove_partial": 0.0}
        # the push counts, summed over the chunks as they are packed (a resumed build, whose
        # saved chunks are not packed here, computes them from the map at the end)
        from lmjx.planner.pushbuild import BuildPushCounts  # (here: the writing process never needs the planner)

        self.push = None if done else BuildPushCounts(robot, reach.failure, reach)
        job = _Job(folder, reach, config, robot.nq, n, sorted(done + units), set(done), writer_threads(), self.tmp)
        # the map's head (root attributes, /robot, /reach) written here: the writing process
        # adds /edges, and needs neither the robot's model nor JAX's runtime
        with h5py.File(self.tmp, "w", track_order=True) as f:
            write_head(f, robot, reach, with_edges=True)
        # A process of its own, whatever the caller's main module is (this lmjx imported from
        # where this one was), in a session of its own (Ctrl-C reaches the build, which stops
        # it), with the CPU as JAX's platform (it imports JAX, but never uses it).
        r_in, w_in = os.pipe()
        r_out, w_out = os.pipe()
        here = str(Path(__file__).resolve().parents[2])
        try:
            self.proc = subprocess.Popen([sys.executable, "-c", _START, here, str(r_in), str(w_out)],
                                         pass_fds=(r_in, w_out), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                         env=dict(os.environ, JAX_PLATFORMS="cpu"), start_new_session=True)  # fmt: skip
        finally:
            os.close(r_in)
            os.close(w_out)
        self.to_writer = Connection(w_in, readable=False)
        self.from_writer = Connection(r_out, writable=False)
        try:  # (the job is sent once the process has started; Ctrl-C meanwhile stops it)
            self.to_writer.send(job)
        except BaseException:
            self.abort()
            raise
        self.feeder = threading.Thread(target=self._feed, name="lmjx-map-feed", daemon=True)
        self.feeder.start()

    def put(self, samples, idx, rolled) -> None:
        """Hand over a computed chunk, packed in units of `PACK_EDGES` sampled edges."""
        t0 = time.perf_counter()
        n = len(samples.which)
        for a, b in chunk_ranges(samples.start + n, PACK_EDGES, samples.start):
            job = self.pool.submit(self._pack, *split_rolled(samples, idx, rolled, a, b))
            while True:
                self._check()
                try:
                    self.queue.put(job, timeout=0.5)
                    break
                except queue.Full:
                    continue
        self.t_wait += time.perf_counter() - t0

    def _pack(self, samples, idx, rolled) -> tuple[int, int]:
        t0 = time.perf_counter()
        chunk = pack_chunk(self.reach, self.config, self.robot, samples, idx, rolled)
        t1 = time.perf_counter()
        chunkfile.save(self.folder, chunk)
        t2 = time.perf_counter()
        if self.push is not None:
            self.push.add(chunk.length, chunk.q)
        self.parts["pack"] += t1 - t0  # summed over the packers: CPU seconds
        self.parts["save"] += t2 - t1
        return chunk.start, chunk.stop

    def _feed(self) -> None:
        """Tell the writing process, in order, which units are saved."""
        sent = 0
        while sent < self.n_units and not self.stop.is_set():
            try:
                job = self.queue.get(timeout=0.5)
            except queue.Empty:
                continue
            try:
                a, b = job.result()
            except BaseException as e:  # a packer's error, handed to the main thread
                self.error = e
                return
            try:
                self.to_writer.send(("unit", a, b))
            except OSError:  # the writing process is gone: _check says why
                return
            sent += 1

    def _check(self) -> None:
        """Raise what stopped the writing process, the packers or the feeder."""
        if self.proc.poll() is not None:
            raise self._writer_failure()
        if self.error is not None:
            raise self.error

    def _writer_failure(self) -> BaseException:
        """The writing process's error (its own message, or how it ended)."""
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(5)
        try:
            if self.from_writer.poll(0.5):
                kind, payload, trace = self.from_writer.recv()
                if kind == "error":
                    return _annotated(payload, trace)
        except (EOFError, OSError, ValueError):
            pass
        return RuntimeError(f"the map-writing process stopped (exit code {self.proc.poll()})")

    def finish(self, out: Path, kernels: dict, edge_seconds: float, device: str) -> dict:
        """Wait for the map, move it to `out` (the partial folder is removed); the build's
        figures back.  `kernels`: the programs' figures (edgestream's `_totals`)."""
        t0 = time.perf_counter()
        self.feeder.join()
        self.pool.shutdown()
        self._check()
        attrs = {"seconds": edge_seconds, "compile_seconds": kernels["compile_seconds"],
                 "rollout_seconds": kernels["rollout_seconds"], "device": device}  # fmt: skip
        try:
            self.to_writer.send(("finish", attrs))
            while not self.from_writer.poll(0.5):
                if self.proc.poll() is not None:
                    break
            kind, w, trace = self.from_writer.recv()
        except (EOFError, OSError):  # it died: how
            raise self._writer_failure() from None
        if kind == "error":
            raise _annotated(w, trace)
        self.proc.wait()
        self.to_writer.close()
        self.from_writer.close()
        t1 = time.perf_counter()
        self.parts["drain"] = t1 - t0  # the writing left when the rollouts end
        # the push counts of the robot's built-in scenarios, here where JAX computes (the
        # states through the device once), added to the map before it is moved to `out`
        push = store_push_counts(self.tmp, self.robot, summed=self.push)
        if self.push is not None:  # the packers' share, summed over them
            self.parts["push_chunks"] = self.push.seconds
        t1 = time.perf_counter()
        self.parts["push"] = push["push_seconds"]
        store_digest(self.tmp)  # the map read back once, so that evaluations need not
        self.parts["digest"] = time.perf_counter() - t1
        t1 = time.perf_counter()
        os.replace(self.tmp, out)  # (a map already at `out` is freed here)
        t2 = time.perf_counter()
        shutil.rmtree(self.folder, ignore_errors=True)
        self.parts["replace"], self.parts["remove_partial"] = t2 - t1, time.perf_counter() - t2
        self.threads_report = w.pop("threads", None)
        return {
            "edges_sampled": w["edges_sampled"],
            "edges_valid": w["edges_valid"],
            "states": w["states"],
            "rejected": w["rejected"],
            "edge_steps": w["edge_steps"],
            "states_evaluated": w["states_evaluated"],
            "seconds": round(edge_seconds, 4),
            "rollout_seconds": round(kernels["rollout_seconds"], 4),
            "rollout_timing": {k: round(v, 4) for k, v in kernels["rollout_timing"].items()},
            "rollout_copied_bytes": kernels["rollout_copied_bytes"],
            "ik_seconds": round(kernels["ik_seconds"], 4),
            "compile_seconds": round(kernels["compile_seconds"], 4),
            "write_seconds": round(w["timing"]["write_states"] + w["timing"]["write_edges"], 4),
            "pack_seconds": round(self.parts["pack"] + self.parts["save"], 4),
            "packers": self.packers,
            "writer_threads": w["threads_used"],
            "wait_seconds": round(self.t_wait, 4),
            "finish_seconds": round(w["timing"]["index"] + w["timing"]["close"], 4),
            "push_seconds": push["push_seconds"],
            "writer_timing": {k: round(v, 4) for k, v in {**w["timing"], **self.parts}.items()},
            "edge_steps_per_s": round(w["edge_steps"] / max(kernels["rollout_seconds"], 1e-9), 1),
            # each process's own high-water mark (their sum bounds the build's)
            "peak_memory_gb": {"build": round(_peak_rss() / 1e9, 3), "writer": round(w["peak_rss"] / 1e9, 3)},
            "bytes_per_state": w["bytes_per_state"],
            "raw_bytes_per_state": w["raw_bytes_per_state"],
        }

    def abort(self, wait: bool = False) -> None:
        """Stop the writing process, the feeder and the packers (an interrupted or failed
        build), and remove the map it was writing; the pipes closed.  `wait`: for the packers
        saving a chunk (a failed build, which then leaves no temporary file behind; an
        interrupted one leaves at once)."""
        self.stop.set()
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.pool.shutdown(wait=wait, cancel_futures=True)
        self.tmp.unlink(missing_ok=True)
        for conn in (self.to_writer, self.from_writer):
            conn.close()


# The writing process's program: lmjx from the build's folder (then off the path again, so
# that it shadows nothing), its pipes' descriptors from the command line.
_START = (
    "import sys; sys.path.insert(0, sys.argv[1]); import lmjx; sys.path.pop(0); import lmjx.edges.mapwriter as m; "
    "m.writer_process(int(sys.argv[2]), int(sys.argv[3]))"
)


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
        result = _Appender(job, inbox).run()
        if sampler is not None:
            result["threads"] = sampler.stop() | {"process": "writer"}
        outbox.send(("done", result, ""))
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

    def __init__(self, job: _Job, inbox) -> None:
        self.job, self.inbox = job, inbox
        self.ready: set[tuple[int, int]] = set()  # units the build's process says are saved
        self.timing = {"waits": 0.0, "read": 0.0, "write_states": 0.0, "write_edges": 0.0, "index": 0.0,
                       "close": 0.0}  # fmt: skip
        self.totals = {"counts": np.zeros(job.reach.labels.size, np.int64), "rejected": np.zeros(len(reasons()),
                       np.int64), "rolled_out": 0, "evaluated": 0, "states": 0, "first_edge": []}  # fmt: skip
        self.file = h5py.File(job.tmp, "r+")  # its head written by the build's process
        self.w = EdgeWriter(self.file, job.config, job.reach, job.nq, threads=job.threads)

    def _next_unit(self) -> None:
        kind, *rest = self.inbox.recv()
        if kind != "unit":
            raise RuntimeError(f"the map writer got '{kind}' before every chunk")
        self.ready.add((rest[0], rest[1]))

    def _read(self, a: int, b: int) -> tuple[dict, dict]:
        t0 = time.perf_counter()
        arrays, head = chunkfile.read(self.job.folder, a, b, APPENDED)
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
        ds = write_index(self.w.group, job.reach, offset, None)
        write_index_edges(ds, job.folder, job.ranges, t["first_edge"], offset)
        t1 = time.perf_counter()
        rejected = {r: int(k) for r, k in zip(reasons(), t["rejected"], strict=True)}
        steps = t["rolled_out"] * job.config.steps
        sizes = self.w.close({"edges_sampled": job.n, "rejected": rejected, "edge_steps": steps,
                              "states_evaluated": t["evaluated"], **attrs})  # fmt: skip
        self.file.close()
        self.timing["index"] = t1 - t0
        self.timing["close"] = time.perf_counter() - t1
        return {"edges_sampled": job.n, "edges_valid": self.w.n_edges, "states": t["states"], "rejected": rejected,
                "edge_steps": steps, "states_evaluated": t["evaluated"], "timing": self.timing,
                "threads_used": job.threads, "peak_rss": _peak_rss(), **sizes}  # fmt: skip


def _annotated(e: BaseException, trace: str) -> BaseException:
    """The writing process's exception, with its traceback there as a note (but for a
    user's error, whose message says it all)."""
    if not isinstance(e, LmjxError):
        e.add_note(f"in the map-writing process:\n{trace}")
    return e


def _peak_rss() -> int:
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
    ds: h5py.Dataset, folder: Path, ranges: list[tuple[int, int]], first_edge: list[int], offset: np.ndarray
) -> None:
    """The index's edge ids, sorted by cell then edge, a range of cells at a time (each
    range at most INDEX_PAIRS pairs, read from every saved chunk).  Each chunk's pairs are
    sorted by (cell, edge) and the chunks come in edge order, so every pair's place is
    known without sorting: its cell's start (`offset`), plus the pairs earlier chunks put
    there, plus its rank among its chunk's pairs of that cell."""
    n_cells = len(offset) - 1
    c0 = 0
    while c0 < n_cells:
        c1 = max(c0 + 1, int(np.searchsorted(offset, offset[c0] + INDEX_PAIRS, side="right")) - 1)
        c1 = min(c1, n_cells)
        out = np.empty(int(offset[c1] - offset[c0]), np.int32)
        fill = (offset[c0:c1] - offset[c0]).astype(np.int64)  # each cell's next free place in `out`
        for (a, b), e0 in zip(ranges, first_edge, strict=True):
            pairs, _ = chunkfile.read(folder, a, b, ("index_cell", "index_edge"))
            cell, edge = pairs["index_cell"], pairs["index_edge"]
            lo, hi = np.searchsorted(cell, [c0, c1])
            if hi == lo:
                continue
            c = cell[lo:hi].astype(np.int64) - c0
            count = np.bincount(c, minlength=c1 - c0)
            rank = np.arange(hi - lo) - (np.cumsum(count) - count)[c]
            out[fill[c] + rank] = edge[lo:hi] + np.int32(e0)
            fill += count
        if len(out):
            ds[offset[c0] : offset[c1]] = out
        c0 = c1
