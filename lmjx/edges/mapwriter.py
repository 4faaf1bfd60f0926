"""The map writing of a streamed build (`lmjx build-map`): packing computed chunks into the
partial folder, and a process of its own appending them to the HDF5 map.

In the build's process, `packer_threads()` threads pack each computed chunk's valid edges
with their spatial-index entries (`bundle.pack_chunk`) and save them to the partial folder
(`chunkfile`); a feeder thread tells the writing process, in edge order, which are saved.

The writing process (`writer_process`: a clean interpreter, with its own interpreter
lock) reads the chunk files ahead on a few threads, appends them in order to
`<partial>/map-<pid>.h5.tmp` with `mapfile.EdgeWriter` (compression and chunk writes on its own
threads), at the end sorts the spatial index from the chunk files, and, the map closed,
completes its content digest (from the chunk files and the map's small datasets:
`mapappend`) while the build's process computes its push counts from it
(the build's process adds both before the map is moved into place).  Measured on 2 H200s
(benchmarks/RESULTS.md): in the build's process, beside some 45 busy threads, the
HDF5 writes waited on the interpreter lock and on h5py's lock in turn, and the map writer
set a 2-GPU build's pace; in a process of its own they do not compete with the rollouts'
host work.

The process is started at the beginning of a build (`WriterProcess`), so that its start
overlaps the preflight and the reach map, and is handed its job by a thread, so that the
build's first chunk never waits for it.  It runs in a process group of its own, so Ctrl-C
reaches only the build, which stops it; it ends when the build's process dies (its pipe closes); a
rerun deletes the map it was writing.
"""

from __future__ import annotations

import contextlib
import os
import queue
import shutil
import subprocess
import threading
import time
from concurrent.futures import CancelledError, Future, ThreadPoolExecutor
from pathlib import Path

from lmjx.edges import chunkfile
from lmjx.edges.chunk import EdgeChunk, chunk_ranges, pack_chunk
from lmjx.edges.mapappend import Job, peak_rss
from lmjx.edges.sampling import split_rolled
from lmjx.mapfile.bundle import BundleConfig, reasons
from lmjx.mapfile.digest import DIGEST_ATTR
from lmjx.mapfile.h5 import h5open
from lmjx.mapfile.pushcounts import write_push_counts
from lmjx.mapfile.write import IndexGrid, edges_group, push_counts_of, write_head
from lmjx.model.robot import Robot
from lmjx.reach.reachability import ReachResult
from lmjx.runtime.child import annotated, start_child
from lmjx.runtime.cores import usable_cores

# Sampled edges packed (and saved to the partial folder) at a time; not part of the result
# (LMJX_PACK_EDGES overrides it: the tests use small units).  A build with fewer edges than
# a unit per packer packs units of fewer, down to MIN_PACK_EDGES (`unit_edges`).
PACK_EDGES = int(os.environ.get("LMJX_PACK_EDGES", 1 << 16))
MIN_PACK_EDGES = 1 << 13
# the chunk arrays the writing process appends (the index pairs are read at the end)
APPENDED = tuple(k for k in EdgeChunk.ARRAYS if k != "index_edge")
WRITER = "the map-writing process"  # (where its errors say they happened)


def unit_edges(edges: int, packers: int) -> int:
    """Sampled edges per packing unit of a build computing `edges` with `packers` threads:
    `PACK_EDGES`, or fewer (not under `MIN_PACK_EDGES`, nor over `PACK_EDGES`) where that
    leaves packers idle.  A GPU's 100,000-edge build is one chunk: in units of 65,536, two
    of its five packers packed it while the rollouts were done and the rest waited."""
    return min(PACK_EDGES, max(MIN_PACK_EDGES, -(-edges // max(1, packers))))


def packer_threads() -> int:
    """Threads packing computed chunks: a third of the cores this process may use, 1 to 12."""
    return max(1, min(12, usable_cores() // 3))


def writer_threads() -> int:
    """Threads compressing and writing the map in the writing process: up to 8 (the
    compression of a 2-GPU build's states needs about 2 cores)."""
    return max(1, min(8, usable_cores()))


class WriterProcess:
    """The writing process, started ahead of its job (`MapWriter`), so that its start (a
    clean interpreter importing h5py, numpy and lmjx's map code) overlaps the build's reach
    map: a process of its own, whatever the caller's main module is (this lmjx imported from
    where this one was), in a process group of its own (Ctrl-C reaches the build, which stops it),
    with the CPU as JAX's platform.  It waits for its job on its pipe, and ends when the pipe
    closes: `stop` ends one never given a job (a build that stopped before its edges)."""

    def __init__(self) -> None:
        self.proc, self.to_writer, self.from_writer = start_child(
            "lmjx.edges.mapappend", "writer_process", dict(os.environ, JAX_PLATFORMS="cpu")
        )

    def stop(self) -> None:
        """End the process (where it still runs) and close its pipes; again: nothing."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for conn in (self.to_writer, self.from_writer):
            conn.close()

    def __enter__(self) -> WriterProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


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
        process: WriterProcess | None = None,
    ) -> None:
        t_start = time.perf_counter()
        self.folder, self.reach, self.config, self.robot = folder, reach, config, robot
        self.packers = packer_threads()
        self.unit = unit_edges(sum(b - a for a, b in todo), self.packers)
        units = [u for a, b in todo for u in chunk_ranges(b, self.unit, a)]
        self.n_units = len(units)
        # the map being written: a name of this run's own (a writing process a killed run left
        # behind, until it notices, keeps writing its own file, unlinked here)
        for old in folder.glob("map*.h5.tmp"):
            old.unlink(missing_ok=True)
        self.tmp = folder / f"map-{os.getpid()}.h5.tmp"
        self.pool = ThreadPoolExecutor(self.packers, thread_name_prefix="lmjx-pack")
        most = max((b - a for a, b in todo), default=1)
        # units being packed here: per device, a chunk's units and 4 more (on 2 H200s, 6 in
        # all kept the packers from keeping up: benchmarks/RESULTS.md)
        self.room = threading.Semaphore(devices * (-(-most // self.unit) + 4))
        # every claimed unit's slot, in edge order (`claim`): done when the unit is saved,
        # here (`put`) or by a peer process (`saved`); the feeder hands them over in order
        self.queue: queue.Queue = queue.Queue()
        self.slots: dict[int, Future] = {}
        self.slots_lock = threading.Lock()
        self.peers = None  # `peers.Peers`, whose failure `_check` raises
        self.error: BaseException | None = None  # what stopped the packers or the feeder
        self.stop = threading.Event()  # the feeder's stop (abort)
        self.threads_report: dict | None = None  # the writing process's LMJX_THREAD_PROFILE report
        self.t_wait = 0.0
        # packers' seconds (summed), the final wait, the content digest (`mapfile.digest`: the
        # writing process's, beside the push counts), the wait for it after the push counts,
        # moving the map to `out`, removing the partial folder (and "push": the push counts'
        # seconds at the end, "push_chunks": the packers' share; "start": the build's thread here)
        self.parts = {"start": 0.0, "pack": 0.0, "save": 0.0, "drain": 0.0, "digest": 0.0, "digest_wait": 0.0,
                      "replace": 0.0, "remove_partial": 0.0}  # fmt: skip
        # the push counts, summed over the chunks as they are packed (a resumed build, whose
        # saved chunks are not packed here, computes them from the map at the end); their
        # scenarios' goal fields made on a thread of their own (one that does not keep an
        # interrupted build from ending), so that the first chunk does not wait for them
        from lmjx.mapfile.pushbuild import BuildPushCounts  # (here: the writing process never needs the planner)

        self.push: _Background | None = None
        if not done:
            self.push = _Background(lambda: BuildPushCounts(robot, reach.failure, reach), "lmjx-push-fields")
        self.job = Job(folder, robot.nq, n, sorted(done + units), set(done), writer_threads(), self.tmp,
                       IndexGrid.of(reach), config.steps, reasons(), APPENDED)  # fmt: skip
        # the map's head (root attributes, /robot, /reach, /edges' settings) written here: the
        # writing process adds /edges' datasets, and needs neither the robot's model nor JAX
        with h5open(self.tmp, "w", track_order=True) as f:
            write_head(f, robot, reach, with_edges=True)
            edges_group(f, config)
        self.process = process if process is not None else WriterProcess()
        self.proc = self.process.proc
        self.to_writer, self.from_writer = self.process.to_writer, self.process.from_writer
        # the feeder hands the job over first (the process may still be starting: the build's
        # thread goes on), then the units as they are saved
        self.feeder = threading.Thread(target=self._feed, name="lmjx-map-feed", daemon=True)
        self.job_sent = threading.Event()
        self.feeder.start()
        self.parts["start"] = time.perf_counter() - t_start  # the build's wait here, before its first chunk

    def claim(self, a: int, b: int) -> None:
        """Chunk [a, b) is the next one computed (by this process or a peer): its units'
        slots join the feeder's order.  Called in edge order, one call at a time."""
        with self.slots_lock:
            for ua, _ in chunk_ranges(b, self.unit, a):
                slot: Future = Future()
                self.slots[ua] = slot
                self.queue.put(slot)

    def saved(self, a: int, b: int) -> None:
        """A peer saved unit [a, b) of a chunk it claimed."""
        with self.slots_lock:
            slot = self.slots.pop(a)
        slot.set_result((a, b))

    def failed(self, error: BaseException, starts: set[int] | None = None) -> None:
        """The units starting at `starts` (None: every unit not yet saved) will not be:
        their slots fail with `error`, which stops the feeder and then the build."""
        with self.slots_lock:
            lost = [a for a in self.slots if starts is None or a in starts]
            slots = [self.slots.pop(a) for a in lost]
        for slot in slots:
            slot.set_exception(error)

    def put(self, samples, idx, rolled) -> None:
        """Hand over a computed chunk (`claim`ed before), packed in units of `unit` sampled
        edges (`unit_edges`)."""
        t0 = time.perf_counter()
        n = len(samples.which)
        for a, b in chunk_ranges(samples.start + n, self.unit, samples.start):
            while not self.room.acquire(timeout=0.5):
                self._check()
            self._check()
            with self.slots_lock:
                slot = self.slots.pop(a)
            job = self.pool.submit(self._pack, *split_rolled(samples, idx, rolled, a, b))
            job.add_done_callback(lambda done, slot=slot: self._packed(done, slot))
        self.t_wait += time.perf_counter() - t0

    def _packed(self, done: Future, slot: Future) -> None:
        """A unit's packing ended (or was cancelled: a build stopping): its slot says so."""
        self.room.release()
        if done.cancelled():
            slot.cancel()
        elif done.exception() is not None:
            slot.set_exception(done.exception())  # type: ignore[arg-type]
        else:
            slot.set_result(done.result())

    def _pack(self, samples, idx, rolled) -> tuple[int, int]:
        t0 = time.perf_counter()
        chunk = pack_chunk(self.reach, self.config, self.robot, samples, idx, rolled)
        t1 = time.perf_counter()
        chunkfile.save(self.folder, chunk)
        t2 = time.perf_counter()
        if self.push is not None:
            self.push.result().add(chunk.length, chunk.q)
        self.parts["pack"] += t1 - t0  # summed over the packers: CPU seconds
        self.parts["save"] += t2 - t1
        return chunk.start, chunk.stop

    def _feed(self) -> None:
        """Hand the writing process its job, then tell it, in order, which units are saved."""
        try:
            self.to_writer.send(self.job)
        except OSError:  # the writing process is gone (or stopped: `abort`): _check says why
            return
        self.job_sent.set()
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
        if self.peers is not None:
            self.peers.check()
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
                    return annotated(payload, trace, WRITER)
        except (EOFError, OSError, ValueError):
            pass
        return RuntimeError(f"{WRITER} stopped (exit code {self.proc.poll()})")

    def finish(self, out: Path, kernels: dict, edge_seconds: float, device: str) -> dict:
        """Wait for the map, move it to `out` (the partial folder is removed); the build's
        figures back.  `kernels`: the programs' figures (edgestream's `_totals`)."""
        t0 = time.perf_counter()
        self.feeder.join()
        self.pool.shutdown()
        self._check()
        attrs = {"seconds": edge_seconds, "compile_seconds": kernels["compile_seconds"],
                 "rollout_seconds": kernels["rollout_seconds"], "device": device}  # fmt: skip
        self._send(("finish", attrs))
        w = self._receive("done")
        t1 = time.perf_counter()
        self.parts["drain"] = t1 - t0  # the writing left when the rollouts end
        # The map is closed: the writing process completes its content digest (`mapfile.digest`,
        # so that evaluations need not read the map for it) while this one computes the push
        # counts of the robot's built-in scenarios (their keys, the counts summed over the
        # chunks already; a resumed build's from the map, here where JAX computes); both are
        # added to the map before it is moved to `out`.
        summed = self.push.result() if self.push is not None else None
        entries, push_attrs = push_counts_of(self.tmp, self.robot, summed=summed)
        if summed is not None:  # the packers' share, summed over them
            self.parts["push_chunks"] = summed.seconds
        t2 = time.perf_counter()
        digest, self.parts["digest"], digest_from = self._receive("digest")
        self.parts["digest_wait"] = time.perf_counter() - t2
        self.proc.wait()
        self.to_writer.close()
        self.from_writer.close()
        with h5open(self.tmp, "r+") as f:
            write_push_counts(f["edges"], entries, push_attrs)
            f.attrs[DIGEST_ATTR] = digest
        push = {"push_seconds": round(time.perf_counter() - t1 - self.parts["digest_wait"], 4)}
        self.parts["push"] = push["push_seconds"]
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
            # where the content digest read the edge states: "chunk files" (raw), or "map" (`mapappend.digest`)
            "digest_from": digest_from,
            "edge_steps_per_s": round(w["edge_steps"] / max(kernels["rollout_seconds"], 1e-9), 1),
            # each process's own high-water mark (their sum bounds the build's)
            "peak_memory_gb": {"build": round(peak_rss() / 1e9, 3), "writer": round(w["peak_rss"] / 1e9, 3)},
            "bytes_per_state": w["bytes_per_state"],
            "raw_bytes_per_state": w["raw_bytes_per_state"],
        }

    def _send(self, message: tuple) -> None:
        """Send the writing process `message`; its failure raised where it is gone."""
        try:
            self.to_writer.send(message)
        except OSError:
            raise self._writer_failure() from None

    def _receive(self, expected: str):
        """The writing process's next message, of kind `expected`: its payload; its error
        (or how it ended) raised."""
        try:
            while not self.from_writer.poll(0.5):
                if self.proc.poll() is not None:
                    break
            kind, payload, trace = self.from_writer.recv()
        except (EOFError, OSError):  # it died: how
            raise self._writer_failure() from None
        if kind == "error":
            raise annotated(payload, trace, WRITER)
        if kind != expected:
            raise RuntimeError(f"the map writer sent '{kind}', not '{expected}'")
        return payload

    def abort(self, wait: bool = False) -> None:
        """Stop the writing process, the feeder and the packers (an interrupted or failed
        build), and remove the map it was writing; the pipes closed.  `wait`: for the packers
        saving a chunk (a failed build, which then leaves no temporary file behind; an
        interrupted one leaves at once)."""
        self.stop.set()
        self.failed(CancelledError())  # (the feeder waits for no unit any more)
        self.process.stop()
        self.pool.shutdown(wait=wait, cancel_futures=True)
        self.tmp.unlink(missing_ok=True)


class _Background:
    """fn() on a daemon thread of its own; `result` waits for its value (or raises its error)."""

    def __init__(self, fn, name: str) -> None:
        self.fn, self.value, self.error = fn, None, None
        self.thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            self.value = self.fn()
        except BaseException as e:
            self.error = e

    def result(self):
        self.thread.join()
        if self.error is not None:
            raise self.error
        return self.value
