"""Maps of any size: `lmjx build-map` in bounded memory, streamed to HDF5, resumable.

The work, for a map `<out>`:
  1. preflight: the output's size and the time it will take, estimated from measured rates
     (`RATES`); a file system without the room for it stops the build before it starts,
     and a build of more than a day needs `yes=True` (`--yes`);
  2. the Reach-Ability map, kept in `<out>.partial/reach.h5`;
  3. the edges in chunks [a, b) of the sampling order: two host threads per device each
     take whole chunks, drawing, solving and rolling them out on their device (while one
     prepares or collects, the other's work runs); in edge order, packers pack each chunk's
     valid edges with their spatial-index entries (`bundle.EdgeChunk`) and save them,
     byte-shuffled and deflated, to `<out>.partial/edges-<a>-<b>.npz` (atomically), and a
     writer thread appends them to the map being written in the partial folder (every
     dataset compressed and written on all cores: `mapfile.EdgeWriter`);
  4. at the end the spatial index (sorted cell range by cell range, `INDEX_PAIRS` pairs at
     a time, from the saved chunks), then the map is renamed to `<out>` and the partial
     folder removed.
Memory stays bounded whatever the number of edges: two chunks per device in flight, a few
packing units, one index range at the end.  Disk: the partial chunks and the map side by
side.

Resumable: killed at any point (kill -9 included), the same command starts again from what
`<out>.partial` holds: saved chunks are kept (and read back into the map in their turn),
missing ones computed; a build with other parameters refuses to touch it.  Ctrl-C leaves nothing at `<out>`.  The
chunk size is not part of the result: edges are drawn from counter-based streams
(`bundle.edge_uniforms`), so the same seed gives the same datasets for any chunking and any
number of devices or processes.

Several devices of one process: each runs whole chunks with its own programs and threads,
so the host work of preparing and collecting launches grows with the devices too.  Several
hosts: `jax.distributed` (`sharding.init_distributed`), every launch split over all devices
(`sharding`), every process computes its share, process 0 reads and writes the files and
tells the others which chunks are left.
"""

from __future__ import annotations

import collections
import json
import os
import re
import shutil
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import h5py
import numpy as np

from . import __version__, threadprof
from .batching import device_description
from .bundle import (
    BundleConfig,
    EdgeChunk,
    EdgeKernels,
    chunk_ranges,
    draw_edges,
    pack_chunk,
    reasons,
    roll_out,
    solve_starts,
    split_rolled,
)
from .errors import ConfigError, OutputPathError
from .failure import Failure
from .fileio import check_writable
from .mapfile import (
    DEFLATE_LEVEL,
    PER_EDGE,
    EdgeWriter,
    deflate,
    load_map,
    write_head,
    write_index,
    write_reach_map,
)
from .progress import Progress
from .reach import ReachConfig, ReachResult, reach_map
from .robot import Robot

INDEX_PAIRS = 32 * 2**20  # spatial-index pairs sorted at a time when assembling (256 MB)
CHUNK_FILE = re.compile(r"^edges-(\d+)-(\d+)\.npz$")
# Measured rates for the preflight (benchmarks/RESULTS.md): edges per second after
# compilation, per accelerator or per CPU core, and what the files take per sampled edge
# (case 2: a quarter of the sampled edges are kept, 51 states each).
RATES = {"gpu": 60_000.0, "cpu_core": 170.0}
COMPILE_SECONDS = {"gpu": 40.0, "cpu": 60.0}
MAP_BYTES_PER_EDGE = 620.0  # the finished map
PARTIAL_BYTES_PER_EDGE = 600.0  # the chunks in <out>.partial, shuffled and deflated (567 measured)
DAY = 86_400.0


@dataclass
class Preflight:
    edges: int
    map_bytes: float
    disk_bytes: float  # partial chunks + the map, at the end of the build
    seconds: float
    free_bytes: int
    devices: int
    basis: str

    def lines(self) -> list[str]:
        return [
            f"preflight: {self.edges:,} edges -> a map of about {_size(self.map_bytes)} "
            f"({_size(self.disk_bytes)} of disk while it is built; {_size(self.free_bytes)} free), "
            f"about {_duration(self.seconds)} ({self.basis})"
        ]


def _size(b: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if b < 1000 or unit == "TB":
            return f"{b:.0f} {unit}" if unit == "B" else f"{b:.1f} {unit}"
        b /= 1000
    return f"{b:.1f} TB"


def _duration(s: float) -> str:
    if s < 120:
        return f"{s:.0f} s"
    if s < 2 * 3600:
        return f"{s / 60:.0f} min"
    if s < 2 * DAY:
        return f"{s / 3600:.1f} h"
    return f"{s / DAY:.1f} days"


def preflight(n: int, out: Path, devices: int, platform: str) -> Preflight:
    """Estimated size and time of a build of n edges (before any work)."""
    gpu = platform != "cpu"
    rate = RATES["gpu"] * devices if gpu else RATES["cpu_core"] * (os.cpu_count() or 1)
    seconds = n / rate + COMPILE_SECONDS["gpu" if gpu else "cpu"]
    where = f"an H100/H200 x {devices}" if gpu else f"a CPU core x {os.cpu_count()}"
    basis = f"{rate:,.0f} edges/s, from rates measured on {where}"
    parent = out.parent if str(out.parent) else Path(".")
    return Preflight(
        n,
        n * MAP_BYTES_PER_EDGE,
        n * (MAP_BYTES_PER_EDGE + PARTIAL_BYTES_PER_EDGE),
        seconds,
        shutil.disk_usage(parent).free,
        devices,
        basis,
    )


# Sampled edges packed (and saved to the partial folder) at a time; not part of the result
# (LMJX_PACK_EDGES overrides it: the tests use small units).
PACK_EDGES = int(os.environ.get("LMJX_PACK_EDGES", 1 << 16))


def packer_threads() -> int:
    """Threads packing computed chunks: a third of the host's cores, 1 to 12."""
    return max(1, min(12, (os.cpu_count() or 1) // 3))


def partial_path(out: str | Path) -> Path:
    out = Path(out)
    return out.with_name(out.name + ".partial")


def _plan(robot: Robot, failure: Failure, reach_cfg: ReachConfig, config: BundleConfig) -> dict:
    """What a partial build holds (a resume must match it)."""
    reach = {k: v for k, v in asdict(reach_cfg).items() if k not in ("strategy", "chunk", "traced_locks")}
    return json.loads(
        json.dumps(
            {
                "lmjx_version": __version__,
                "robot_model_hash": robot.model_hash,
                "failure": failure.spec,
                "locked": [list(x) for x in failure.locked],
                "reach": reach,
                "edges": config.content(),
                "n": config.n_edges(),
            },
            default=list,
        )
    )


def saved_chunks(folder: Path) -> list[tuple[int, int]]:
    """The chunk ranges saved in a partial folder, in order (temporary files removed, and
    damaged ones: a chunk's file is not synced to disk, so a crash of the machine, unlike a
    killed build, may leave one unreadable; it is computed again)."""
    ranges = []
    for f in folder.iterdir():
        m = CHUNK_FILE.match(f.name)
        if m:
            try:
                with np.load(f) as z:
                    if set(z.files) != {"meta", *EdgeChunk.ARRAYS}:
                        raise ValueError(f"{f.name}: not a whole chunk")
            except Exception:  # whatever is wrong with it, it is redone
                f.unlink(missing_ok=True)
                continue
            ranges.append((int(m.group(1)), int(m.group(2))))
        elif f.name.startswith(".") and f.name.endswith(".tmp"):
            f.unlink(missing_ok=True)  # a save a kill interrupted
    return sorted(ranges)


def missing_ranges(done: list[tuple[int, int]], n: int, size: int) -> list[tuple[int, int]]:
    """Ranges of [0, n) not covered by `done` (disjoint, sorted), cut into chunks of `size`."""
    todo, at = [], 0
    for a, b in done:
        if a < at:
            raise ConfigError(f"the partial build holds overlapping chunks ({a}-{b}); remove the .partial folder")
        todo += chunk_ranges(a, size, at) if a > at else []
        at = b
    return todo + chunk_ranges(n, size, at)


def _save(folder: Path, chunk: EdgeChunk) -> None:
    """A packed chunk into the partial folder, atomically (a killed build leaves it whole
    or absent), each array byte-shuffled and deflated (`_squeeze`: 567 bytes per sampled
    edge where the plain arrays took about 960).  Not synced to disk chunk by chunk, which
    made every chunk wait for the disk (see `saved_chunks` for a machine crash)."""
    path = folder / f"edges-{chunk.start}-{chunk.stop}.npz"
    tmp = folder / f".{path.name}.{os.getpid()}.tmp"
    arrays = {k: np.ascontiguousarray(getattr(chunk, k)) for k in EdgeChunk.ARRAYS}
    meta = {"rolled_out": chunk.rolled_out, "states_evaluated": chunk.states_evaluated, "seconds": chunk.seconds,
            "arrays": {k: [a.dtype.str, list(a.shape)] for k, a in arrays.items()}}  # fmt: skip
    with open(tmp, "wb") as fh:
        np.savez(fh, meta=np.array(json.dumps(meta)), **{k: _squeeze(a) for k, a in arrays.items()})
    os.replace(tmp, path)


def _squeeze(a: np.ndarray) -> np.ndarray:
    """The array's bytes, shuffled by byte position (as HDF5's shuffle filter) and deflated."""
    shuffled = np.ascontiguousarray(a.reshape(-1).view(np.uint8).reshape(-1, a.dtype.itemsize).T)
    return np.frombuffer(deflate.compress(shuffled, DEFLATE_LEVEL), np.uint8)


def _unsqueeze(z, name: str, meta: dict) -> np.ndarray:
    dtype, shape = meta["arrays"][name]
    dtype = np.dtype(dtype)
    raw = np.frombuffer(deflate.decompress(z[name]), np.uint8)
    return raw.reshape(dtype.itemsize, -1).T.copy().view(dtype).reshape(shape)


def _arrays(folder: Path, a: int, b: int, names: tuple[str, ...]) -> tuple[dict, dict]:
    """Arrays of a saved chunk, and its meta."""
    with np.load(folder / f"edges-{a}-{b}.npz") as z:
        meta = json.loads(str(z["meta"]))
        return {k: _unsqueeze(z, k, meta) for k in names}, meta


def _load(folder: Path, a: int, b: int) -> EdgeChunk:
    arrays, meta = _arrays(folder, a, b, EdgeChunk.ARRAYS)
    return EdgeChunk(start=a, stop=b, rolled_out=meta["rolled_out"], states_evaluated=meta["states_evaluated"],
                     seconds=meta["seconds"], **arrays)  # fmt: skip


def build_map(
    out: str | Path,
    failure: Failure,
    reach_cfg: ReachConfig,
    config: BundleConfig,
    robot: Robot,
    progress: bool = True,
    sharded: bool = True,
    yes: bool = False,
    say=print,
) -> dict:
    """Build (or finish) the map file `out`: reach map + edge bundle, streamed.  Returns a
    summary (for the command line)."""
    import jax

    from . import sharding

    reach_cfg.validate(robot)
    config.validate(robot)
    out = Path(out)
    folder = partial_path(out)
    lead = jax.process_index() == 0
    n = config.n_edges()
    devices = sharding.device_count() if sharded else 1
    if lead:
        check_writable(out, "map file")
        pre = preflight(n, out, devices, jax.default_backend())
        for line in pre.lines():
            say(line)
        done_bytes = sum(f.stat().st_size for f in folder.iterdir()) if folder.is_dir() else 0
        too_long = pre.seconds > DAY and not yes
        if pre.disk_bytes - done_bytes > pre.free_bytes:
            # Both problems in one message: a user who frees room should not then learn about --yes.
            also = f"; it would also take about {_duration(pre.seconds)}: add --yes to start anyway" if too_long else ""
            raise OutputPathError(
                f"not enough room at {out.parent or '.'}: the build needs about {_size(pre.disk_bytes)}, "
                f"{_size(pre.free_bytes)} are free; free some or choose another --out{also}"
            )
        if too_long:
            raise ConfigError(
                f"{n:,} edges would take about {_duration(pre.seconds)} here; add --yes to start anyway "
                "(it can be stopped and resumed), or ask for fewer --edges"
            )
    plan = _plan(robot, failure, reach_cfg, config)
    reach: ReachResult | None = None
    if lead:
        folder.mkdir(parents=True, exist_ok=True)
        plan_path = folder / "plan.json"
        if plan_path.exists():
            if json.loads(plan_path.read_text()) != plan:
                raise ConfigError(
                    f"{folder} holds an unfinished build with other parameters; rerun that command, or remove "
                    "the folder to start this one"
                )
        else:
            tmp = plan_path.with_name(".plan.json.tmp")
            tmp.write_text(json.dumps(plan, indent=1, sort_keys=True))
            os.replace(tmp, plan_path)
        if (folder / "reach.h5").exists():
            reach = load_map(folder / "reach.h5", robot).reach
    # One process with several devices: each device runs whole chunks of its own (its own
    # programs, and host threads preparing and collecting its work), so that the host work
    # scales with the devices too.  Several processes: every launch spread over all devices.
    split = sharded and jax.process_count() == 1 and len(jax.local_devices()) > 1
    size = config.edges_per_chunk(devices) if jax.process_count() > 1 else config.edges_per_job()
    done = saved_chunks(folder) if lead else []
    todo = missing_ranges(done, n, size) if lead else []
    if jax.process_count() > 1:  # everyone follows process 0's record of what is left
        from jax.experimental import multihost_utils

        count = int(multihost_utils.broadcast_one_to_all(np.int64(len(todo))))
        arr = np.zeros((count, 2), np.int64) if not lead else np.asarray(todo, np.int64).reshape(-1, 2)
        todo = [tuple(int(x) for x in r) for r in np.asarray(multihost_utils.broadcast_one_to_all(arr))]
        has_reach = bool(multihost_utils.broadcast_one_to_all(np.int32(reach is not None)))
    else:
        has_reach = reach is not None
    device = device_description()
    t0 = time.perf_counter()
    if reach is None:
        # every process computes the reach map (the edges are drawn from it)
        reach = reach_map(failure, reach_cfg, robot=robot, progress=progress and lead)
        if lead and not has_reach:
            write_reach_map(folder / "reach.h5", reach, robot)
    t_reach = time.perf_counter() - t0
    half = reach_cfg.object_height / 2
    if split:
        kernel_sets = [EdgeKernels(robot, failure, config, n, False, half, device=d) for d in jax.local_devices()]
    else:
        kernel_sets = [EdgeKernels(robot, failure, config, n, sharded, half)]
    bar = Progress(total=2 * n, desc=f"edges {failure.spec}", enabled=progress and lead, unit="edge")
    bar.update(2 * sum(b - a for a, b in done))
    t1 = time.perf_counter()
    writer = _MapWriter(folder, reach, config, robot, n, done, todo) if lead else None
    main = {"wait": 0.0, "hand_over": 0.0}  # the main thread: waiting for chunks, handing them over
    jobs = {"draw": 0.0, "ik": 0.0, "rollout": 0.0}  # the chunk threads' time, summed

    def job(kernels: EdgeKernels, a: int, b: int):
        t0 = time.perf_counter()
        draws = draw_edges(reach, config, robot, a, b)
        t1 = time.perf_counter()
        samples = solve_starts(draws, kernels, bar)
        t2 = time.perf_counter()
        idx, rolled = roll_out(samples, kernels, bar)
        bar.update(b - a - len(idx))
        for k, v in (("draw", t1 - t0), ("ik", t2 - t1), ("rollout", time.perf_counter() - t2)):
            jobs[k] += v
        return samples, idx, rolled

    # Two threads per device (one process): while one prepares or collects a chunk, the
    # other's work runs on the device.  Several processes launch in one agreed order: one.
    threads = 2 if jax.process_count() == 1 else 1
    sampler = threadprof.from_environment() if lead else None  # LMJX_THREAD_PROFILE: where threads wait
    pools = [ThreadPoolExecutor(threads, thread_name_prefix="lmjx-chunk") for _ in kernel_sets]
    window: collections.deque[Future] = collections.deque()  # chunks in flight, in edge order
    try:
        for k, (a, b) in enumerate(todo):
            i = k % len(kernel_sets)
            window.append(pools[i].submit(job, kernel_sets[i], a, b))
            while len(window) >= threads * len(kernel_sets) or (window and k == len(todo) - 1):
                t = time.perf_counter()
                samples, idx, rolled = window.popleft().result()
                t2 = time.perf_counter()
                if writer is not None:
                    writer.put(samples, idx, rolled)
                main["wait"] += t2 - t
                main["hand_over"] += time.perf_counter() - t2
    finally:
        for pool in pools:
            pool.shutdown(wait=not window, cancel_futures=True)
    compile_seconds = max(ks.compile_seconds for ks in kernel_sets)  # the devices compile side by side
    edge_seconds = time.perf_counter() - t1 - compile_seconds
    summary = {"device": device, "devices": devices, "processes": jax.process_count()}
    if writer is not None:
        summary |= writer.finish(out, _totals(kernel_sets), edge_seconds, device)
        summary["reach_seconds"] = t_reach
        # from the first chunk to the finished file, compilation excluded
        summary["edges_wall_seconds"] = round(time.perf_counter() - t1 - compile_seconds, 4)
        summary["main_timing"] = {k: round(v, 4) for k, v in main.items()}
        summary["chunk_timing"] = {k: round(v, 4) for k, v in jobs.items()}
    threadprof.write_report(sampler)
    bar.close()
    return summary


class _MapWriter:
    """Process 0's map writing, beside the accelerators: `packers` threads pack computed
    chunks and save them to the partial folder (atomically), several at once (numpy and
    the compressor release the interpreter lock, and on a GPU this host work, not the
    rollouts, sets the pace); one thread appends them, in edge order, to the map being
    written there (saved chunks of an earlier run are read back in their turn).  At the
    end: the spatial index, then the map renamed to `out` and the partial folder removed.
    At most a computed chunk's packing units and 4 more are held at a time."""

    def __init__(
        self,
        folder: Path,
        reach: ReachResult,
        config: BundleConfig,
        robot: Robot,
        n: int,
        done: list[tuple[int, int]],
        todo: list[tuple[int, int]],
    ) -> None:
        import queue
        import threading

        self.folder, self.reach, self.config, self.robot, self.n = folder, reach, config, robot, n
        units = [u for a, b in todo for u in chunk_ranges(b, PACK_EDGES, a)]
        self.ranges = sorted(done + units)
        self.saved = set(done)
        self.packers = packer_threads()
        self.pool = ThreadPoolExecutor(self.packers, thread_name_prefix="lmjx-pack")
        # packed or being packed, in order: a computed chunk's units and 4 more (host memory)
        most = max((b - a for a, b in todo), default=1)
        self.queue: queue.Queue = queue.Queue(maxsize=-(-most // PACK_EDGES) + 4)
        self.error: BaseException | None = None
        self.tmp = folder / "map.h5.tmp"
        self.tmp.unlink(missing_ok=True)  # a map a killed run was writing
        self.totals = {"counts": np.zeros(reach.labels.size, np.int64), "rejected": np.zeros(len(reasons()), np.int64),
                       "rolled_out": 0, "evaluated": 0, "states": 0, "first_edge": []}  # fmt: skip
        self.t_wait = 0.0
        # the writer thread's and the packers' time, part by part
        self.parts = {"writer_waits": 0.0, "write_states": 0.0, "write_edges": 0.0, "pack": 0.0, "save": 0.0,
                      "drain": 0.0}  # fmt: skip
        self.thread = threading.Thread(target=self._run, name="lmjx-map-writer", daemon=True)
        self.thread.start()

    def put(self, samples, idx, rolled) -> None:
        """Hand over a computed chunk, packed in units of `PACK_EDGES` sampled edges (blocks
        while the queue is full: a chunk's units and `packers` more)."""
        import queue

        t0 = time.perf_counter()
        n = len(samples.which)
        for a, b in chunk_ranges(samples.start + n, PACK_EDGES, samples.start):
            job = self.pool.submit(self._pack, *split_rolled(samples, idx, rolled, a, b))
            while True:
                if not self.thread.is_alive():
                    raise self.error or RuntimeError("the map writer stopped")
                try:
                    self.queue.put(job, timeout=0.5)
                    break
                except queue.Full:
                    continue
        self.t_wait += time.perf_counter() - t0

    def _pack(self, samples, idx, rolled) -> EdgeChunk:
        t0 = time.perf_counter()
        chunk = pack_chunk(self.reach, self.config, self.robot, samples, idx, rolled)
        t1 = time.perf_counter()
        _save(self.folder, chunk)
        self.parts["pack"] += t1 - t0  # summed over the packers: CPU seconds
        self.parts["save"] += time.perf_counter() - t1
        return chunk

    def _run(self) -> None:
        try:
            self.file = h5py.File(self.tmp, "w", track_order=True)
            write_head(self.file, self.robot, self.reach, with_edges=True)
            self.w = EdgeWriter(self.file, self.config, self.reach, self.robot.nq)
            for a, b in self.ranges:
                t0 = time.perf_counter()
                chunk = _load(self.folder, a, b) if (a, b) in self.saved else self.queue.get().result()
                self.parts["writer_waits"] += time.perf_counter() - t0
                self._append(chunk)
        except BaseException as e:  # handed to the main thread
            self.error = e

    def _append(self, c: EdgeChunk) -> None:
        t = self.totals
        t["first_edge"].append(self.w.n_edges)
        t0 = time.perf_counter()
        self.w.add_states(c.q, c.qd, c.p)
        t1 = time.perf_counter()
        starts = np.concatenate([[0], np.cumsum(c.length)[:-1]]).astype(np.int64)
        q_start = c.q[starts] if len(c.length) else np.zeros((0, self.robot.nq), np.float32)
        self.w.add_edges({name: q_start if name == "q_start" else getattr(c, name) for name in PER_EDGE})
        t["counts"] += np.bincount(c.index_cell, minlength=len(t["counts"]))
        t["rejected"] += c.rejected
        t["rolled_out"] += c.rolled_out
        t["evaluated"] += c.states_evaluated
        t["states"] += len(c.q)
        self.parts["write_states"] += t1 - t0
        self.parts["write_edges"] += time.perf_counter() - t1

    def finish(self, out: Path, kernels: dict, edge_seconds: float, device: str) -> dict:
        """Wait for the last chunks, write the spatial index, move the map to `out`;
        `kernels`: the programs' figures (`_totals`)."""
        t0 = time.perf_counter()
        self.thread.join()
        self.parts["drain"] = time.perf_counter() - t0  # the writer's work left when the rollouts end
        self.pool.shutdown()
        if self.error is not None:
            raise self.error
        t0 = time.perf_counter()
        t = self.totals
        offset = np.zeros(len(t["counts"]) + 1, np.int64)
        offset[1:] = np.cumsum(t["counts"])
        ds = write_index(self.w.group, self.reach, offset, None)
        _write_index_edges(ds, self.folder, self.ranges, t["first_edge"], offset)
        rejected = {r: int(k) for r, k in zip(reasons(), t["rejected"], strict=True)}
        steps = t["rolled_out"] * self.config.steps
        sizes = self.w.close(
            {
                "edges_sampled": self.n,
                "rejected": rejected,
                "seconds": edge_seconds,
                "compile_seconds": kernels["compile_seconds"],
                "rollout_seconds": kernels["rollout_seconds"],
                "edge_steps": steps,
                "states_evaluated": t["evaluated"],
                "device": device,
            }
        )
        valid = self.w.n_edges
        self.file.close()
        os.replace(self.tmp, out)
        shutil.rmtree(self.folder, ignore_errors=True)
        return {
            "edges_sampled": self.n,
            "edges_valid": valid,
            "states": t["states"],
            "rejected": rejected,
            "edge_steps": steps,
            "states_evaluated": t["evaluated"],
            "seconds": round(edge_seconds, 4),
            "rollout_seconds": round(kernels["rollout_seconds"], 4),
            "rollout_timing": {k: round(v, 4) for k, v in kernels["rollout_timing"].items()},
            "rollout_copied_bytes": kernels["rollout_copied_bytes"],
            "ik_seconds": round(kernels["ik_seconds"], 4),
            "compile_seconds": round(kernels["compile_seconds"], 4),
            "write_seconds": round(self.parts["write_states"] + self.parts["write_edges"], 4),
            "pack_seconds": round(self.parts["pack"] + self.parts["save"], 4),
            "packers": self.packers,
            "wait_seconds": round(self.t_wait, 4),
            "finish_seconds": round(time.perf_counter() - t0, 4),
            "writer_timing": {k: round(v, 4) for k, v in self.parts.items()},
            "edge_steps_per_s": round(steps / max(kernels["rollout_seconds"], 1e-9), 1),
            **sizes,
        }


def _totals(kernel_sets: list[EdgeKernels]) -> dict:
    """The build's kernel figures: compilation as the longest of the devices' (they compile
    side by side), run times summed over the devices (device-seconds)."""
    timing: dict[str, float] = {}
    for ks in kernel_sets:
        for k, v in ks.rollout.timing.items():
            timing[k] = timing.get(k, 0.0) + v
    return {
        "compile_seconds": max(ks.compile_seconds for ks in kernel_sets),
        "rollout_seconds": sum(ks.rollout.kernel_seconds for ks in kernel_sets),
        "rollout_timing": timing,
        "rollout_copied_bytes": sum(ks.rollout.copied_bytes for ks in kernel_sets),
        "ik_seconds": sum(ks.ik.kernel_seconds for ks in kernel_sets),
    }


def _write_index_edges(
    ds: h5py.Dataset, folder: Path, ranges: list[tuple[int, int]], first_edge: list[int], offset: np.ndarray
) -> None:
    """The index's edge ids, sorted by cell then edge, a range of cells at a time (each
    range at most INDEX_PAIRS pairs, read from every saved chunk)."""
    n_cells = len(offset) - 1
    c0 = 0
    while c0 < n_cells:
        c1 = max(c0 + 1, int(np.searchsorted(offset, offset[c0] + INDEX_PAIRS, side="right")) - 1)
        c1 = min(c1, n_cells)
        cells, edges = [], []
        for (a, b), e0 in zip(ranges, first_edge, strict=True):
            pairs, _ = _arrays(folder, a, b, ("index_cell", "index_edge"))
            cell, edge = pairs["index_cell"], pairs["index_edge"]
            sel = (cell >= c0) & (cell < c1)
            cells.append(cell[sel])
            edges.append(edge[sel].astype(np.int64) + e0)
        cell = np.concatenate(cells)
        edge = np.concatenate(edges)
        order = np.argsort(cell, kind="stable")  # chunks come in edge order, each sorted by (cell, edge)
        if len(order):
            ds[offset[c0] : offset[c1]] = edge[order].astype(np.int32)
        c0 = c1
