"""Maps of any size: `lmjx build-map` in bounded memory, streamed to HDF5, resumable.

The work, for a map `<out>`:
  1. preflight: the output's size and the time it will take, estimated from measured rates
     (`RATES`); a file system without the room for it stops the build before it starts,
     and a build of more than a day needs `yes=True` (`--yes`);
  2. the Reach-Ability map, kept in `<out>.partial/reach.h5`;
  3. the edges in chunks [a, b) of the sampling order: host threads per device
     (`CHUNK_THREADS`) each take whole chunks, drawing, solving and rolling them out on their
     device (while one's work runs there, the others prepare or collect theirs), with a
     chunk more per device queued on several devices; in edge order, packers pack each chunk's
     valid edges with their spatial-index entries (`bundle.EdgeChunk`) and save them to
     `<out>.partial/edges-<a>-<b>.chunk` (`chunkfile`), and a process of its own appends
     them to the map being written in the partial folder (`mapwriter`);
  4. at the end, in that process, the spatial index (sorted cell range by cell range,
     from the saved chunks); then the map is renamed to `<out>` and the partial folder
     removed.
Memory stays bounded whatever the number of edges: a few chunks per device in flight (so it
grows with the devices: 7 GB on one H200, 14 GB on two for case 2), a few packing units per
device, a few chunks read ahead by the writing process, one index range at the end.
Disk: the partial chunks and the map side by side.

Resumable: killed at any point (kill -9 included), the same command starts again from what
`<out>.partial` holds: saved chunks are kept (and read back into the map in their turn),
missing ones computed; a build with other parameters refuses to touch it.  Ctrl-C leaves
nothing at `<out>`.  The chunk size is not part of the result: edges are drawn from
counter-based streams (`bundle.edge_uniforms`), so the same seed gives the same datasets for
any chunking and any number of devices or processes.

Several devices of one process: each runs whole chunks with its own programs and threads,
so the host work of preparing and collecting launches grows with the devices too.  Several
hosts: `jax.distributed` (`sharding.init_distributed`), every launch split over all devices
(`sharding`), every process computes its share, process 0 reads and writes the files and
tells the others which chunks are left.
"""

from __future__ import annotations

import collections
import contextlib
import json
import os
import shutil
import sys
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np

from lmjx.edges.chunk import chunk_ranges
from lmjx.edges.chunkfile import NAME, saved_chunks
from lmjx.edges.compiling import (
    BackgroundCompile,
    PresetCompiler,
    first_then_together,
    preset_programs,
    preset_record,
)
from lmjx.edges.existing import build_plan, difference
from lmjx.edges.index import capsule_ends_kernel, index_totals, warm_index
from lmjx.edges.mapwriter import MapWriter, WriterProcess
from lmjx.edges.peers import PeerPrograms, Peers, PeerWork, peer_environment
from lmjx.edges.peers import enabled as peers_enabled
from lmjx.edges.preflight import DAY, Preflight, Work, preflight
from lmjx.edges.preflight import duration_text as _duration
from lmjx.edges.preflight import size_text as _size
from lmjx.edges.sampling import EdgeKernels, draw_edges, roll_out, solve_starts, start_cells
from lmjx.errors import ConfigError, OutputPathError
from lmjx.mapfile.bundle import BundleConfig
from lmjx.mapfile.read import load_map
from lmjx.mapfile.write import write_reach_map
from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.reach.reachability import ReachConfig, ReachResult, reach_ik, reach_map
from lmjx.runtime import threadprof
from lmjx.runtime.batching import backend, device_description
from lmjx.runtime.cache import cache_dir, in_jax_cache
from lmjx.runtime.compiletime import compile_wall_seconds, telling_compiled
from lmjx.runtime.devices import own_device
from lmjx.runtime.fileio import check_writable
from lmjx.runtime.progress import Progress


def partial_path(out: str | Path) -> Path:
    out = Path(out)
    return out.with_name(out.name + ".partial")


def _kept(out: Path, plan: dict, overwrite: bool, lead: bool) -> bool:
    """Whether `out` already holds the map of `plan` (then the build keeps it: True); refuses
    any other file there unless `overwrite` (OutputPathError).  Process 0 looks, and tells
    the others."""
    import jax

    verdict, differs = 0, None  # 0: build, 1: keep the map there, 2: refused
    if lead and out.exists() and not out.is_dir():
        differs = difference(out, plan)
        verdict = 1 if differs is None and not overwrite else 2 if differs is not None and not overwrite else 0
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        verdict = int(multihost_utils.broadcast_one_to_all(np.int32(verdict)))
    if verdict == 2:
        what = differs or "a file process 0 refuses to replace"
        raise OutputPathError(f"--out {out} already holds {what}; add --overwrite to replace it, or choose another "
                              "--out")  # fmt: skip
    return verdict == 1


def missing_ranges(done: list[tuple[int, int]], n: int, size: int) -> list[tuple[int, int]]:
    """Ranges of [0, n) not covered by `done` (disjoint, sorted), cut into chunks of `size`."""
    todo, at = [], 0
    for a, b in done:
        if a < at:
            raise ConfigError(f"the partial build holds overlapping chunks ({a}-{b}); remove the .partial folder")
        todo += chunk_ranges(a, size, at) if a > at else []
        at = b
    return todo + chunk_ranges(n, size, at)


# The interpreter's thread switch interval during a build.  Python's default, 5 ms, lets a
# thread back from a C call that released the interpreter lock (a copy, a file write, a
# device wait) wait up to 5 ms for it while a dozen others run Python code; measured on 2
# H200s (benchmarks/RESULTS.md): the 2-GPU edge loop 12.4 s at 5 ms, 9.8 s at
# 0.5 ms; one GPU's unchanged.
SWITCH_INTERVAL = 0.0005
# Chunk threads per device in one process, and chunks per device submitted beyond them
# (queued, or done and not yet handed over), for one device and for several: while one thread's chunk
# runs on its device, the others draw, copy and place theirs.  Measured on 2 H200s
# (benchmarks/RESULTS.md), 5M edges after compilation: 2 GPUs 10.3-10.5 s with
# (2, 0), 8.7 s with (3, 1); 1 GPU 17.1-17.7 s with (2, 0), 15.1 s with 3 threads, but then
# 8.5 GB of host memory, over the 8 GB a one-GPU 5M-edge build keeps to.
CHUNK_THREADS = {"one": (2, 0), "several": (3, 1)}  # (threads, ahead)


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
    compile_presets: bool | None = None,
    overwrite: bool = False,
) -> dict:
    """Build (or finish) the map file `out`: reach map + edge bundle, streamed.  Returns a
    summary (for the command line).  The interpreter's switch interval is at most
    `SWITCH_INTERVAL` meanwhile (restored after).

    A file already at `out` is kept when it is the map this build writes (`existing`): the
    summary is then {"kept": True}; any other file is replaced only when `overwrite`, else
    OutputPathError.  A build that fails removes the partial folder it started unless it
    holds computed edges (then `say` is told it is kept, for a rerun to resume); an
    interrupted one keeps it where it holds the edges or the reach map.

    `compile_presets`: also compile the programs of the robot's other preset failures
    (`lmjx.edges.compiling`) where the cache lacks them, after the build's own, and wait for
    them before returning; None: on accelerators (on a CPU the compiling would take the
    cores the build needs), with a cache folder, in one process."""
    import jax

    folder = partial_path(out)
    started = jax.process_index() == 0 and not folder.exists()  # this run makes the partial folder
    before = sys.getswitchinterval()
    sys.setswitchinterval(min(before, SWITCH_INTERVAL))
    try:
        with contextlib.ExitStack() as stack:  # (the writing process, where the build stops before handing it its job)
            return _build_map(out, failure, reach_cfg, config, robot, progress, sharded, yes, say, compile_presets,
                              overwrite, stack)  # fmt: skip
    except BaseException as e:
        if jax.process_index() == 0:
            kept = leave_partial(folder, started, interrupted=isinstance(e, KeyboardInterrupt))
            if kept is not None and not isinstance(e, KeyboardInterrupt):
                say(kept)
        raise
    finally:
        sys.setswitchinterval(before)


def leave_partial(folder: Path, started: bool, interrupted: bool) -> str | None:
    """After a failed or interrupted build: remove the partial folder where nothing in it can
    be resumed and this run `started` it (a folder an earlier run left is kept), and any
    temporary file in a folder kept.  Resumable: saved chunks of edges, and after an
    interrupt the reach map too (a failure is not resumed from the reach map alone: the
    rerun would meet the same failure).  A line saying what is kept, or None."""
    if not folder.is_dir():
        return None
    for f in folder.iterdir():
        if f.name.endswith(".tmp"):
            f.unlink(missing_ok=True)
    chunks = any(NAME.match(f.name) for f in folder.iterdir())
    if started and not chunks and not (interrupted and (folder / "reach.h5").exists()):
        shutil.rmtree(folder, ignore_errors=True)
        return None
    return f"kept {folder}: run the same command to resume, or remove it"


def _build_map(
    out: Path | str,
    failure: Failure,
    reach_cfg: ReachConfig,
    config: BundleConfig,
    robot: Robot,
    progress: bool,
    sharded: bool,
    yes: bool,
    say,
    compile_presets: bool | None,
    overwrite: bool,
    stack: contextlib.ExitStack,
) -> dict:
    import jax

    from lmjx.runtime import sharding

    t_start = time.perf_counter()
    reach_cfg.validate(robot)
    config.validate(robot)
    out = Path(out)
    folder = partial_path(out)
    lead = jax.process_index() == 0
    n = config.n_edges()
    devices = sharding.device_count() if sharded else 1
    plan = build_plan(robot, failure, reach_cfg, config)
    if _kept(out, plan, overwrite, lead):
        return {"kept": True}
    # the map's writing process, started now so that its start overlaps the preflight and the
    # reach map (`stack` stops it where the build ends before the map writer takes it)
    process = stack.enter_context(WriterProcess()) if lead else None
    # One process with several devices: each device runs whole chunks of its own (its own
    # programs, and host threads preparing and collecting its work), so that the host work
    # scales with the devices too: the first in this process, each other one in a peer
    # process of its own (`peers`; in this process too where LMJX_PEERS=0).  Several
    # processes: every launch spread over all devices.
    local = jax.local_devices()
    split = sharded and jax.process_count() == 1 and len(local) > 1
    half = reach_cfg.object_height / 2
    peers: Peers | None = None
    if split and peers_enabled(local[0].platform) and all(peer_environment(d) is not None for d in local[1:]):
        nx, ny = (len(a) for a in reach_cfg.grid())
        programs = PeerPrograms(str(robot.path), failure, config, half, reach_cfg.chunk, (nx, ny, reach_cfg.cell),
                                min(sys.getswitchinterval(), SWITCH_INTERVAL), local[0].platform)  # fmt: skip
        peers = stack.enter_context(Peers(local[1:], programs))
        kernel_sets = [EdgeKernels(robot, failure, config, False, half, device=local[0], ik_chunk=reach_cfg.chunk)]
        stack.enter_context(own_device(None))  # this process's index and push work on its device
    elif split:
        kernel_sets = [EdgeKernels(robot, failure, config, False, half, device=d, ik_chunk=reach_cfg.chunk)
                       for d in jax.local_devices()]  # fmt: skip
    else:
        kernel_sets = [EdgeKernels(robot, failure, config, sharded, half, ik_chunk=reach_cfg.chunk)]
    pre: Preflight | None = None
    if lead:
        check_writable(out, "map file")
        xs, ys = reach_cfg.grid()
        chunk = config.edges_per_chunk(devices) if jax.process_count() > 1 else config.edges_per_job()
        work = Work.of(n, len(xs) * len(ys), reach_cfg.attempts, reach_cfg.restarts, config.ik_restarts, config.steps,
                       chunk)  # fmt: skip
        cached = _cached_stages(robot, failure, reach_cfg, kernel_sets[0])
        pre = preflight(n, out, devices, jax.default_backend(), work, cached)
        for line in pre.lines():
            say(line)
        to_compile = [stage for stage, held in cached.items() if not held]
        if to_compile and progress:  # (minutes in which nothing else shows: said, then each program as it is done)
            compiling = pre.stages.get("compile", 0.0)
            say(f"compiling the programs of {', '.join(to_compile)} for this machine (once: kept in the cache folder), "
                f"about {_duration(compiling)}")  # fmt: skip
            stack.enter_context(telling_compiled(lambda name, seconds: say(f"compiled {name} in {seconds:.0f} s")))
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
    size = config.edges_per_chunk(devices) if jax.process_count() > 1 else config.edges_per_job()
    done = saved_chunks(folder) if lead else []
    todo = missing_ranges(done, n, size) if lead else []
    if lead and (done or reach is not None):
        kept = sum(b - a for a, b in done)
        say(
            f"resuming the build kept in {folder}: {kept:,} of {n:,} edges already computed"
            f"{' (and the reach map)' if reach is not None else ''}"
        )
    if jax.process_count() > 1:  # everyone follows process 0's record of what is left
        from jax.experimental import multihost_utils

        count = int(multihost_utils.broadcast_one_to_all(np.int64(len(todo))))
        arr = np.zeros((count, 2), np.int64) if not lead else np.asarray(todo, np.int64).reshape(-1, 2)
        todo = [tuple(int(x) for x in r) for r in np.asarray(multihost_utils.broadcast_one_to_all(arr))]
        has_reach = bool(multihost_utils.broadcast_one_to_all(np.int32(reach is not None)))
    else:
        has_reach = reach is not None
    device = device_description()
    capsules = capsule_ends_kernel(robot)  # one per process: its compiling before this build is not this build's
    capsules_before = capsules.compile_seconds
    presets = None
    if compile_presets is None:
        compile_presets = backend() != "cpu" and cache_dir() is not None
    elif compile_presets and lead and cache_dir() is None:
        say("other failures' programs are not compiled ahead: there is no cache to keep them (--cache-dir off)")
    if compile_presets and jax.process_count() == 1 and cache_dir() is not None:
        programs = preset_programs(robot, failure, reach_cfg, config, half)
        presets = PresetCompiler(programs, record=preset_record(programs))
    # The edges' programs and the spatial index's (its capsule program and its passes) compile in
    # a thread of their own while the reach map is computed (they do not depend on it); then, for
    # later builds, the other presets' programs.
    xs, ys = reach_cfg.grid()
    index_before = index_totals()
    background = BackgroundCompile(
        [
            first_then_together([ks.warm for ks in kernel_sets]),  # each device's: one program for all
            capsules.compile,
            lambda: warm_index(robot, len(xs), len(ys), reach_cfg.cell),  # on the grid's size only
        ],
        presets,
    )
    t0 = time.perf_counter()
    reach_compile = None  # the reach map's compiling, when it is computed here
    if reach is None:
        # every process computes the reach map (the edges are drawn from it)
        reach = reach_map(failure, reach_cfg, robot=robot, progress=progress and lead)
        reach_compile = reach.compile_seconds
        start_cells(reach)  # a failure that reaches no cell stops here, not after compiling the edges' programs
        if lead and not has_reach:
            write_reach_map(folder / "reach.h5", reach, robot)
    t_reach = time.perf_counter() - t0
    background.wait_own()
    compiled_before = max(ks.compile_seconds for ks in kernel_sets)
    # (each edge counted twice: its start solved, then its rollout)
    bar = Progress(total=n, desc=f"edges {failure.spec}", enabled=progress and lead, unit="edge", steps_per_unit=2)
    bar.update(2 * sum(b - a for a, b in done))
    t1 = time.perf_counter()
    writer: MapWriter | None = None
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

    # Threads per device (CHUNK_THREADS) in one process; several processes launch in one
    # agreed order: one each, nothing ahead.
    if jax.process_count() == 1:
        threads, ahead = CHUNK_THREADS["several" if len(kernel_sets) > 1 else "one"]
    else:
        threads, ahead = 1, 0
    sampler = threadprof.from_environment() if lead else None  # LMJX_THREAD_PROFILE: where threads wait
    pools = [ThreadPoolExecutor(threads, thread_name_prefix="lmjx-chunk") for _ in kernel_sets]
    window: collections.deque[Future] = collections.deque()  # chunks in flight, in edge order
    peer_results: list[dict] = []
    try:
        writer = MapWriter(folder, reach, config, robot, n, done, todo, len(kernel_sets), process) if lead else None
        claims = Claims(todo, writer)
        if peers is not None:
            assert writer is not None
            writer.peers = peers
            peers.begin(
                PeerWork(reach, str(folder), writer.unit, writer.packers, writer.push is not None),
                claims.claim_for_peer,
                lambda a, b: (writer.saved(a, b), bar.update(2 * (b - a))),
                lambda peer, error: writer.failed(error, claims.peer_units(peer)),
            )  # fmt: skip
        k = 0
        while True:
            got = claims.claim()
            if got is not None:
                i = k % len(kernel_sets)
                window.append(pools[i].submit(job, kernel_sets[i], *got))
                k += 1
            while len(window) >= (threads + ahead) * len(kernel_sets) or (window and got is None):
                t = time.perf_counter()
                samples, idx, rolled = window.popleft().result()
                t2 = time.perf_counter()
                if writer is not None:
                    writer.put(samples, idx, rolled)
                main["wait"] += t2 - t
                main["hand_over"] += time.perf_counter() - t2
            if got is None:
                break
        if peers is not None:
            t = time.perf_counter()
            peer_results = peers.finish(lambda i: bool(claims.peer_units(i)))  # (their last units saved)
            main["peers_wait"] = time.perf_counter() - t
            if writer is not None and writer.push is not None:
                for r in peer_results:
                    writer.push.result().merge(**r["push"])
    except BaseException as e:
        if writer is not None:
            writer.abort(wait=not isinstance(e, KeyboardInterrupt))
        if peers is not None:
            peers.stop()
        raise
    finally:
        for pool in pools:
            pool.shutdown(wait=not window, cancel_futures=True)
    # the devices compile side by side; what compiled before the edges began is not theirs
    compile_seconds = max(ks.compile_seconds for ks in kernel_sets) - compiled_before
    edge_seconds = time.perf_counter() - t1 - compile_seconds
    summary = {"device": device, "devices": devices, "processes": jax.process_count()}
    stages = _compile_by_stage(robot, failure, reach_cfg, reach_compile, kernel_sets)
    if writer is not None:
        try:
            summary |= writer.finish(out, _totals(kernel_sets, stages["edges"], peer_results), edge_seconds, device)
        except BaseException as e:
            writer.abort(wait=not isinstance(e, KeyboardInterrupt))
            raise
    # after the packers (which index the chunks: `finish` waits for them)
    index_figures = index_totals(since=index_before)
    # the index's: its capsule program and its passes' programs
    stages["index"] = round(capsules.compile_seconds - capsules_before + index_figures.get("compile_seconds", 0.0), 4)
    if writer is not None:
        summary["compile_by_stage"] = stages
        summary["reach_seconds"] = t_reach
        # from the first chunk to the finished file, compilation excluded
        summary["edges_wall_seconds"] = round(time.perf_counter() - t1 - compile_seconds, 4)
        summary["main_timing"] = {k: round(v, 4) for k, v in main.items()}
        summary["chunk_timing"] = {k: round(v, 4) for k, v in jobs.items()}
        if peers is not None:  # each peer process's figures: its start, its share, its times
            summary["peers"] = [{k: v for k, v in r.items() if k != "push"} for r in peer_results]
            summary["peers_idle"] = len(peers.dismissed)  # (stopped still starting: the build was done first)
        # the spatial index (`lmjx.edges.index`): its passes, the borderline items settled on the
        # host, its programs' compilation (none where this process or the cache has them)
        summary["index"] = index_figures
        # the estimate made before the build (`lmjx.edges.preflight`), and the build's wall time
        # from this call to the finished file (the process's start not included)
        if pre is not None:
            summary["preflight"] = pre.summary()
        summary["build_seconds"] = round(time.perf_counter() - t_start, 4)
        # the wall time during which something compiled (stages compiled side by side once)
        summary["compile_wall_seconds"] = round(compile_wall_seconds(t_start), 4)
    threadprof.write_report(sampler, writer.threads_report if writer is not None else None)
    bar.close()
    if background.presets is not None:
        background.finish(say)
        summary["compiled_for_later"] = background.presets.summary()
    return summary


def _cached_stages(robot: Robot, failure: Failure, reach_cfg: ReachConfig, kernels: EdgeKernels) -> dict:
    """Per compile stage of the preflight, whether JAX's persistent cache holds its programs,
    looked up without compiling (`in_jax_cache`): the reach map's IK program, the edges' IK
    and rollout programs; the index's and the push counts' programs, compiled by every build
    of the edges, are counted with them.  None where it cannot tell; {} without a cache."""
    if cache_dir() is None:
        return {}
    reach_kernel = reach_ik(robot, failure, reach_cfg).kernel
    reach = in_jax_cache(reach_kernel.lower()[0])
    ik = reach if kernels.ik.kernel.placed == reach_kernel.placed else in_jax_cache(kernels.ik.kernel.lower()[0])
    rollout = in_jax_cache(kernels.rollout.lower()[0])
    edges = None if ik is None or rollout is None else ik and rollout
    return {"reach": reach, "edges": edges, "index": edges, "push": edges}


def _compile_by_stage(
    robot: Robot,
    failure: Failure,
    reach_cfg: ReachConfig,
    reach_compile: float | None,
    kernel_sets: list[EdgeKernels],
) -> dict[str, float]:
    """The build's compiling (or loading compiled programs from the cache) by stage, each
    program counted once: the reach map's IK program (`reach_compile`: the reach map's wait
    for it, whichever thread compiled it; None when the reach map was resumed), the edges'
    programs less that one where they share it (the longest of the devices': they compile
    side by side)."""
    reach_program = None if reach_compile is None else reach_ik(robot, failure, reach_cfg).kernel.placed

    def edges(ks: EdgeKernels) -> float:
        shared = ks.ik.kernel.placed == reach_program
        return ks.rollout.compile_seconds + (0.0 if shared else ks.ik.compile_seconds)

    return {
        "reach": round(reach_compile or 0.0, 4),
        "edges": round(max(edges(ks) for ks in kernel_sets), 4),
    }


def _totals(kernel_sets: list[EdgeKernels], compile_seconds: float, peers: list[dict] | None = None) -> dict:
    """The build's kernel figures: the edges' compilation (`_compile_by_stage`), run times
    summed over the devices (device-seconds), the peer processes' (`peers`) included."""
    peers = peers or []
    timing: dict[str, float] = {}
    for t in [ks.rollout.timing for ks in kernel_sets] + [r["rollout_timing"] for r in peers]:
        for k, v in t.items():
            timing[k] = timing.get(k, 0.0) + v
    return {
        "compile_seconds": compile_seconds,
        "rollout_seconds": sum(ks.rollout.kernel_seconds for ks in kernel_sets)
        + sum(r["rollout_seconds"] for r in peers),
        "rollout_timing": timing,
        "rollout_copied_bytes": sum(ks.rollout.copied_bytes for ks in kernel_sets)
        + sum(r["rollout_copied_bytes"] for r in peers),
        "ik_seconds": sum(ks.ik.kernel_seconds for ks in kernel_sets) + sum(r["ik_seconds"] for r in peers),
    }


class Claims:
    """The chunks left to compute, claimed in edge order by this process (`claim`) and its
    peer processes (`claim_for_peer`); each claim registers its units with the map writer
    (`MapWriter.claim`), which hands them over in edge order whoever computes them."""

    def __init__(self, todo: list[tuple[int, int]], writer: MapWriter | None) -> None:
        self.todo, self.writer = todo, writer
        self.next = 0
        self.lock = threading.Lock()
        self.by_peer: dict[int, set[int]] = {}  # peer -> the starts of its claimed units

    def _claim(self) -> tuple[int, int] | None:
        if self.next == len(self.todo):
            return None
        a, b = self.todo[self.next]
        self.next += 1
        if self.writer is not None:
            self.writer.claim(a, b)
        return a, b

    def claim(self) -> tuple[int, int] | None:
        """The next chunk for this process (None: none left)."""
        with self.lock:
            return self._claim()

    def claim_for_peer(self, peer: int) -> tuple[int, int] | None:
        """The next chunk for peer `peer` (None: none left)."""
        with self.lock:
            got = self._claim()
            if got is not None and self.writer is not None:
                units = self.by_peer.setdefault(peer, set())
                units.update(u for u, _ in chunk_ranges(got[1], self.writer.unit, got[0]))
            return got

    def peer_units(self, peer: int) -> set[int]:
        """The starts of the units peer `peer` claimed."""
        with self.lock:
            return set(self.by_peer.get(peer, set()))
