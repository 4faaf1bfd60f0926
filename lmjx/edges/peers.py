"""A streamed build's peer processes: on a host with several GPUs, one process per GPU
beyond the first computes chunks of edges beside the build's own process.

Why processes: a build's per-chunk host work (drawing edges, collecting rollouts, packing
them with their index pairs, their push counts, saving them) runs on some forty threads.
In one process with two GPUs those threads share one interpreter lock and one address
space (every large buffer mapped and unmapped under one lock: `runtime.hostmem`), and a
second GPU made a 5,000,000-edge build no faster (benchmarks/RESULTS.md).  A peer is a
clean interpreter that sees one GPU: it runs the same programs as a one-GPU build (JAX's
persistent cache holds them once for every GPU of a kind) and the same pipeline, so the
host work grows with the GPUs.

The work is shared chunk by chunk: a peer asks the build's process for the next chunk of
the sampling order whenever it has room, computes it, packs it in the build's units, saves
each unit to the partial folder (`chunkfile`: what the writing process reads) and says so;
the build's process hands the units to the writing process in edge order, whichever
process computed them.  Edges come from counter-based streams, so the map is the same
whichever process computes which chunk (and the same as a one-GPU build's).  Its push
counts, summed over its units, come back at the end and are added to the build's.

A peer is started with the build (`Peers`), so that its start (importing JAX, starting
the GPU, loading the programs) overlaps the build's reach map; it runs in a process group
of its own (Ctrl-C reaches the build, which stops it) and ends when its pipe closes.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import pickle
import re
import signal
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from lmjx.edges.chunk import chunk_ranges
from lmjx.mapfile.bundle import BundleConfig
from lmjx.model.failure import Failure
from lmjx.reach.reachability import ReachResult
from lmjx.runtime.child import annotated, start_child

ENV = "LMJX_PEERS"  # "0": a build on several GPUs runs them all in its own process (`enabled`)
CHUNK_THREADS = 2  # a peer's chunk threads (a one-GPU build's: `stream.CHUNK_THREADS["one"]`)
UNITS_AHEAD = 4  # units a peer's packers may have waiting beyond one chunk's


def enabled(platform: str) -> bool:
    """Whether a build on several local devices of `platform` ("gpu", "cpu", ...) runs all
    but the first in peers: on GPUs, unless `ENV` is "0"; elsewhere where it is "1" (host
    devices share the cores a peer would add: the tests use it)."""
    choice = os.environ.get(ENV, "").strip()
    return choice == "1" or (platform == "gpu" and choice != "0")


def peer_environment(device: Any) -> tuple[dict[str, str], int] | None:
    """The environment of a peer that runs on `device` (a JAX device of this process), and
    the device's number among the peer's local devices; None where there is no peer for it
    (a platform other than GPUs and the host).  On GPUs the peer sees the GPUs this process
    sees (the same environment): a JAX process seeing another set of devices compiles its
    programs again rather than load them from JAX's persistent cache (measured on 2 H200s:
    a peer shown one GPU was not ready before a 5,000,000-edge build ended)."""
    env = dict(os.environ)
    if device.platform == "cpu":  # (host devices, as the tests make them: one in the peer)
        flags = re.sub(r"--xla_force_host_platform_device_count=\d+", "", env.get("XLA_FLAGS", "")).strip()
        env["XLA_FLAGS"] = flags
        env["JAX_PLATFORMS"] = "cpu"
        return env, 0
    if device.platform != "gpu":
        return None
    # the GPUs' memory taken as needed: the build's process and the peers share every GPU's
    env["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"
    return env, int(device.id)


@dataclass(frozen=True)
class PeerPrograms:
    """What defines a peer's programs, sent as it starts (it loads them while the build
    computes its reach map): the robot, the failure, the edges' settings, the reach grid."""

    robot: str  # the robot's MJCF path (`load_robot`)
    failure: Failure
    config: BundleConfig
    half: float  # the object's half height (the start IK's cube)
    ik_chunk: int | None
    grid: tuple[int, int, float]  # the reach grid's nx, ny and cell (the index's programs)
    switch_interval: float
    platform: str = "gpu"  # its devices' platform (JAX's `Device.platform`)
    device: int = 0  # its device: the peer's jax.local_devices()[device] (`Peers` sets it)


@dataclass(frozen=True)
class PeerWork:
    """What a peer needs besides its programs to compute and pack chunks of a build: the
    reach map, where to save the units, how to cut chunks into them, whether to count pushes."""

    reach: ReachResult
    folder: str
    unit: int  # sampled edges per packing unit (`mapwriter.unit_edges`)
    packers: int
    push: bool  # sum the built-in scenarios' push counts (a build that is not resumed)


class Peers:
    """The build's side: peer processes started ahead of their job (`__init__`), given it
    with `begin`, then served from a thread each: chunks claimed for them (`claim`), their
    saved units reported (`saved(a, b)`), their end collected (`finish`)."""

    def __init__(self, devices: list[Any], programs: PeerPrograms) -> None:
        self.procs: list[subprocess.Popen] = []
        self.to_peer: list[Connection] = []
        self.from_peer: list[Connection] = []
        self.devices = devices
        self.results: list[dict | None] = [None] * len(devices)
        self.error: BaseException | None = None
        self.threads: list[threading.Thread] = []
        self.dismissed: set[int] = set()  # peers stopped with nothing to do (`finish`)
        self.numbers: list[int] = []  # each peer's device among its local devices
        try:
            for device in devices:
                placed = peer_environment(device)
                if placed is None:
                    raise RuntimeError(f"no peer process can be placed on {device}")
                env, number = placed
                self.numbers.append(number)
                proc, to_peer, from_peer = start_child("lmjx.edges.peers", "peer_process", env)
                self.procs.append(proc)
                self.to_peer.append(to_peer)
                self.from_peer.append(from_peer)
                with contextlib.suppress(OSError):  # (a peer gone already: `begin` says so)
                    self.to_peer[-1].send(dataclasses.replace(programs, device=number))
        except BaseException:
            self.stop()
            raise

    def begin(
        self,
        work: PeerWork,
        claim: Callable[[int], tuple[int, int] | None],
        saved: Callable[[int, int], None],
        failed: Callable[[int, BaseException], None],
    ) -> None:
        """Send each peer `work` and serve it from a thread: `claim(peer)` gives it its next
        chunk (None: no more), `saved(a, b)` is told of each unit it saved, `failed(peer,
        error)` of its failure (also kept in `error`, which `check` raises)."""
        for i in range(len(self.procs)):
            t = threading.Thread(target=self._serve, args=(i, work, claim, saved, failed), name=f"lmjx-peer-{i}",
                                 daemon=True)  # fmt: skip
            t.start()
            self.threads.append(t)

    def _serve(self, i: int, work: PeerWork, claim, saved, failed) -> None:
        """Peer i's thread: its work sent (here: a reach map fills the pipe until the peer,
        loading its programs, reads it), then its requests and reports answered."""
        conn_in, conn_out = self.from_peer[i], self.to_peer[i]
        try:
            conn_out.send(work)
            while True:
                kind, *rest = conn_in.recv()
                if kind == "want":
                    conn_out.send(("chunk", claim(i)))
                elif kind == "saved":
                    saved(*rest)
                elif kind == "done":
                    self.results[i] = rest[0]
                    return
                elif kind == "error":
                    self._fail(i, annotated(*rest, self._where(i)), failed)
                    return
        except (EOFError, OSError):
            if i not in self.dismissed:
                self._fail(i, self._gone(i), failed)
        except BaseException as e:  # (the build's side failed serving it: the build stops)
            self._fail(i, e, failed)

    def _gone(self, i: int) -> BaseException:
        """Why peer i's pipe closed: the error it sent before it ended, else how it ended."""
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.procs[i].wait(5)
        try:
            while self.from_peer[i].poll(0.5):
                kind, *rest = self.from_peer[i].recv()
                if kind == "error":
                    return annotated(*rest, self._where(i))
        except (EOFError, OSError, ValueError):
            pass
        return RuntimeError(f"{self._where(i)} stopped (exit code {self.procs[i].poll()})")

    def _where(self, i: int) -> str:
        return f"the build's peer process on {self.devices[i]}"

    def _fail(self, i: int, error: BaseException, failed) -> None:
        if self.error is None:
            self.error = error
        failed(i, error)

    def check(self) -> None:
        """Raise a peer's failure."""
        if self.error is not None:
            raise self.error

    def finish(self, claimed: Callable[[int], bool]) -> list[dict]:
        """Once every chunk is claimed: wait for the end (its last unit saved) of each peer
        that `claimed` a chunk, stop those that did not (still starting: a build done
        before they were ready); the figures of the former back, in order."""
        for i, proc in enumerate(self.procs):
            if not claimed(i):
                self.dismissed.add(i)
                proc.terminate()
        for t in self.threads:
            while t.is_alive():
                t.join(0.5)
        self.check()
        for i, proc in enumerate(self.procs):
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(10)
            self.to_peer[i].close()
            self.from_peer[i].close()
        return [r for r in self.results if r is not None]

    def stop(self) -> None:
        """End the peers (where they still run) and close their pipes; again: nothing."""
        for proc in self.procs:
            if proc.poll() is None:
                proc.terminate()
        for proc in self.procs:
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for conn in (*self.to_peer, *self.from_peer):
            conn.close()

    def __enter__(self) -> Peers:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def peer_process(inbox_fd: int, outbox_fd: int) -> None:
    """A peer's entry point: its pipes from the build's process."""
    from lmjx.runtime.hostmem import return_large_buffers

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    return_large_buffers()  # as the build's process (lmjx.cli)
    inbox, outbox = Connection(inbox_fd, writable=False), Connection(outbox_fd, readable=False)
    t0 = time.perf_counter()
    try:
        import jax

        devices = jax.local_devices()  # the GPUs started while the build computes its reach map
        try:
            programs = inbox.recv()
        except (EOFError, OSError):  # the build stopped before it was sent whole
            return
        if programs.device >= len(devices) or devices[programs.device].platform != programs.platform:
            raise RuntimeError(f"a peer process for the build's {programs.platform} device {programs.device} sees "
                               f"{devices}")  # fmt: skip
        device = devices[programs.device]
        # every program and transfer not placed otherwise goes to its device, and the index's
        # and the push counts' work (`runtime.devices.own_device`)
        jax.config.update("jax_default_device", device)
        from lmjx.runtime.devices import own_device

        with own_device(device):
            peer = _Peer(programs, device, inbox, outbox, t0)
            result = peer.run(inbox.recv())
        outbox.send(("done", result))
    except (EOFError, BrokenPipeError):
        return  # the build's process is gone
    except BaseException as e:
        trace = traceback.format_exc()
        try:
            pickle.loads(pickle.dumps(e))  # (one whose arguments do not make it again fails in the build)
        except Exception:
            e = RuntimeError(f"{type(e).__name__}: {e}")
        with contextlib.suppress(Exception):  # (the build's process gone)
            outbox.send(("error", e, trace))


class _Peer:
    """A peer's work: its programs loaded (side by side, as it is made), then chunks claimed
    from the build's process, computed on `CHUNK_THREADS` threads, packed in units on
    `work.packers` threads."""

    def __init__(self, programs: PeerPrograms, device: Any, inbox: Connection, outbox: Connection, t0: float) -> None:
        from lmjx.edges.index import capsule_ends_kernel, warm_index
        from lmjx.edges.sampling import EdgeKernels
        from lmjx.mapfile.pushsamples import compile_program
        from lmjx.model.robot import load_robot

        self.programs, self.device, self.inbox, self.outbox, self.t0 = programs, device, inbox, outbox, t0
        self.claim_lock = threading.Lock()  # a request and its answer
        self.send_lock = threading.Lock()
        self.figures = {"chunks": 0, "edges": 0, "draw": 0.0, "ik": 0.0, "rollout": 0.0, "pack": 0.0, "save": 0.0}
        self.figures_lock = threading.Lock()
        sys.setswitchinterval(programs.switch_interval)
        self.robot = robot = load_robot(programs.robot)
        self.start_seconds = time.perf_counter() - t0  # the interpreter, JAX and the GPUs, the robot
        t1 = time.perf_counter()
        # the programs the build's process runs on its first device, placed on this one (JAX's
        # persistent cache holds them once for every GPU of a kind: loaded, not compiled)
        self.kernels = EdgeKernels(robot, programs.failure, programs.config, False, programs.half, device=device,
                                   ik_chunk=programs.ik_chunk)  # fmt: skip
        nx, ny, cell = programs.grid
        steps = [self.kernels.rollout.compile, self.kernels.ik.compile,
                 capsule_ends_kernel(robot, device=device).compile, lambda: warm_index(robot, nx, ny, cell),
                 lambda: compile_program(robot)]  # fmt: skip
        with ThreadPoolExecutor(len(steps), thread_name_prefix="lmjx-compile") as pool:
            for done in [pool.submit(step) for step in steps]:
                done.result()
        self.load_seconds = time.perf_counter() - t1
        self.ready_seconds = time.perf_counter() - t0

    def _send(self, message: tuple) -> None:
        with self.send_lock:
            self.outbox.send(message)

    def _claim(self) -> tuple[int, int] | None:
        with self.claim_lock:
            self._send(("want",))
            kind, chunk = self.inbox.recv()
        assert kind == "chunk", kind
        return chunk

    def run(self, work: PeerWork) -> dict:
        """Claim, compute, pack and save chunks until none is left; the figures back."""
        from lmjx.edges.chunk import pack_chunk
        from lmjx.edges.chunkfile import save
        from lmjx.edges.index import index_totals
        from lmjx.edges.sampling import draw_edges, roll_out, solve_starts, split_rolled
        from lmjx.mapfile.pushbuild import BuildPushCounts

        programs, robot, kernels = self.programs, self.robot, self.kernels
        reach, config, folder = work.reach, programs.config, Path(work.folder)
        # the push counts' scenario fields made beside the first chunk (its packing waits for them)
        making = ThreadPoolExecutor(1, thread_name_prefix="lmjx-push-fields")
        fields = making.submit(BuildPushCounts, robot, programs.failure, reach) if work.push else None
        making.shutdown(wait=False)
        index_before = index_totals()
        most = config.edges_per_job()
        room = threading.Semaphore(-(-most // work.unit) + UNITS_AHEAD)  # units being packed
        errors: list[BaseException] = []
        packs: list[Future] = []

        def pack(samples, idx, rolled) -> None:
            try:
                if errors:  # (the peer is stopping: a unit it cannot save is not packed)
                    return
                t0 = time.perf_counter()
                chunk = pack_chunk(reach, config, robot, samples, idx, rolled)
                t1 = time.perf_counter()
                save(folder, chunk)
                t2 = time.perf_counter()
                if fields is not None:
                    fields.result().add(chunk.length, chunk.q)
                with self.figures_lock:
                    self.figures["pack"] += t1 - t0
                    self.figures["save"] += t2 - t1
                self._send(("saved", chunk.start, chunk.stop))
            except BaseException as e:  # (the chunk threads claim no more; `run` raises it)
                errors.append(e)
                raise
            finally:
                room.release()

        def chunks(pool: ThreadPoolExecutor) -> None:
            try:
                while not errors:
                    got = self._claim()
                    if got is None:
                        return
                    a, b = got
                    t0 = time.perf_counter()
                    draws = draw_edges(reach, config, robot, a, b)
                    t1 = time.perf_counter()
                    samples = solve_starts(draws, kernels)
                    t2 = time.perf_counter()
                    idx, rolled = roll_out(samples, kernels)
                    t3 = time.perf_counter()
                    with self.figures_lock:
                        for k, v in (("draw", t1 - t0), ("ik", t2 - t1), ("rollout", t3 - t2)):
                            self.figures[k] += v
                        self.figures["chunks"] += 1
                        self.figures["edges"] += b - a
                    for ua, ub in chunk_ranges(b, work.unit, a):
                        room.acquire()
                        packs.append(pool.submit(pack, *split_rolled(samples, idx, rolled, ua, ub)))
                    del samples, idx, rolled
            except BaseException as e:
                errors.append(e)

        with ThreadPoolExecutor(work.packers, thread_name_prefix="lmjx-pack") as pool:
            threads = [threading.Thread(target=chunks, args=(pool,), name="lmjx-chunk") for _ in range(CHUNK_THREADS)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
        for f in packs:
            f.result()  # (a packer's error)
        if errors:
            raise errors[0]
        out = {
            "device": str(self.device),
            "start_seconds": round(self.start_seconds, 4),  # the interpreter, JAX and the GPUs, the robot
            "ready_seconds": round(self.ready_seconds, 4),  # ... and the programs loaded (or compiled)
            "load_seconds": round(self.load_seconds, 4),
            "compile_seconds": round(kernels.compile_seconds, 4),
            "rollout_seconds": kernels.rollout.kernel_seconds,
            "rollout_timing": dict(kernels.rollout.timing),
            "rollout_copied_bytes": kernels.rollout.copied_bytes,
            "ik_seconds": kernels.ik.kernel_seconds,
            "index": index_totals(since=index_before),
            **{k: (round(v, 4) if isinstance(v, float) else v) for k, v in self.figures.items()},
        }
        if fields is not None:
            push = fields.result()
            out["push"] = {"counts": push.counts, "edges": push.edges, "seconds": push.seconds}
        return out
