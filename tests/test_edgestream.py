"""Maps of any size (lmjx.edges.stream): streamed builds give the in-memory bundle's datasets
for any chunk size, any number of devices and processes; a killed build resumes to the
uninterrupted file; the preflight refuses what cannot fit or would take days; a map opened
lazily makes the planner's decisions a map read whole makes.

The builds compared are the four-joint test arm's (`tiny_map`, built in chunks of 400 edges
by `lmjx build-map` in the test process: a fraction of the Panda's work and compile time);
the Panda's shared map (`small_map`) is the one whose threads are sampled and that the
planner reads lazily."""

from __future__ import annotations

import json
import signal
import socket
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import TINY_ARM, TINY_MAP, Collected, cli, cli_process, finish, wait_for

from lmjx.edges import chunkfile
from lmjx.edges.chunk import build_bundle
from lmjx.edges.stream import missing_ranges, preflight
from lmjx.mapfile.bundle import BundleConfig
from lmjx.mapfile.read import load_map
from lmjx.mapfile.write import write_map
from lmjx.reach.reachability import ReachConfig

# the test arm's build without its chunk size (each test gives its own)
BUILD = ["build-map", *TINY_MAP[: TINY_MAP.index("--chunk")]]
CHUNK = TINY_MAP[TINY_MAP.index("--chunk") + 1]
RUN_ATTRS = {"seconds", "compile_seconds", "kernel_seconds", "rollout_seconds", "write_seconds", "finish_seconds",
             "edge_steps_per_s", "states_per_s", "device", "devices", "processes"}  # fmt: skip


def datasets(path) -> dict[str, np.ndarray]:
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[...]) if isinstance(obj, h5py.Dataset) else None)
    return out


# The edges' values computed on the devices (states and their per-edge figures): programs
# partitioned over several processes may round them differently in the last bit.
COMPUTED = ("edges/q", "edges/qd", "edges/p", "edges/q_start", "edges/peak_torque_ratio", "edges/peak_velocity_ratio",
            "edges/peak_acceleration_ratio", "edges/min_manipulability")  # fmt: skip


# The push counts' names: hashes of the edges' starts, among others (`pushmap.counts_key`).
PUSH_KEYS = ("edges/push/key",)


def same_datasets(a, b, last_bit: tuple[str, ...] = (), skip: tuple[str, ...] = ()) -> list[str]:
    """The datasets that differ between two map files (but those in `skip`): exactly, or
    (those in `last_bit`) by more than float32 rounding (4e-7 of the value's size, at least
    of 1)."""
    da, db = datasets(a), datasets(b)
    for k in skip:
        da.pop(k, None)
        db.pop(k, None)

    def same(k: str) -> bool:
        if k in last_bit and da[k].shape == db[k].shape:
            return bool(np.all(np.abs(da[k] - db[k]) <= 4e-7 * np.maximum(1.0, np.abs(da[k]))))
        return np.array_equal(da[k], db[k], equal_nan=da[k].dtype.kind == "f")

    return [k for k in sorted(set(da) | set(db)) if k not in da or k not in db or not same(k)]


def attributes(path) -> dict[str, str]:
    """Every attribute of every group, as text, run records (times, devices) aside."""
    out = {}
    with h5py.File(path, "r") as f:
        for where in ["/", *(k for k in f if isinstance(f[k], h5py.Group))]:
            for k, v in f[where].attrs.items():
                if k not in RUN_ATTRS and not k.endswith("_seconds"):
                    out[f"{where}:{k}"] = str(v)
    return out


def test_a_build_reports_where_its_threads_are(small_map):
    """LMJX_THREAD_PROFILE: the sampled threads of the build, grouped, each with its places."""
    groups = json.loads(small_map.with_name("threads.json").read_text())["groups"]
    assert {"MainThread", "lmjx-chunk", "lmjx-map-feed", "lmjx-pack"} <= set(groups)
    assert {"writer/lmjx-map-writer", "writer/lmjx-write", "writer/lmjx-read"} <= set(groups)  # lmjx.edges.mapwriter
    chunk = [where for where, _ in groups["lmjx-chunk"]["top"]]
    assert any(w.split(":")[0] in ("batching.py", "bundle.py", "edgestream.py", "ik_batch.py") for w in chunk)


def test_chunk_size_and_memory_do_not_change_the_datasets(tiny_map, tmp_path, monkeypatch):
    # computed in chunks of 500 and packed in units of 150 (lmjx.edges.mapwriter.PACK_EDGES)
    import lmjx.edges.mapwriter

    monkeypatch.setattr(lmjx.edges.mapwriter, "PACK_EDGES", 150)
    other = tmp_path / "b.h5"
    r = cli(*BUILD, "--chunk", "500", "--out", other).ok()
    assert "preflight:" in r.stderr
    assert same_datasets(tiny_map, other) == []
    assert not Path(str(other) + ".partial").exists()
    # the in-memory bundle (lmjx.edges.chunk.build_bundle, in chunks of 250) writes the same datasets
    from lmjx.model.robot import load_robot

    m = load_map(tiny_map, load_robot(str(TINY_ARM)))
    bundle = build_bundle(m.reach, replace(m.edges.config, build_chunk=250), robot=m.robot)
    whole = tmp_path / "whole.h5"
    write_map(whole, m.reach, bundle, m.robot)
    assert same_datasets(tiny_map, whole) == [] and bundle.n_edges > 100


def test_killed_build_resumes_to_the_same_file(tiny_map, tmp_path):
    """Killed outright (kill -9) after two chunks, the same command finishes the build: the
    datasets and attributes of the uninterrupted build (the same command, the same seed,
    the same file); a saved chunk whose bytes changed stops it first, in one line."""
    out = tmp_path / "resumed.h5"
    partial = Path(str(out) + ".partial")
    args = [*BUILD, "--chunk", CHUNK, "--out", out]
    p = cli_process(*args)
    err = Collected(p.stderr)
    wait_for(lambda: len(list(partial.glob("edges-*.chunk"))) >= 2, p, "two saved chunks")
    p.send_signal(signal.SIGKILL)
    p.wait(timeout=60)
    err.finish()
    assert not out.exists()
    kept = sorted(partial.glob("edges-*.chunk"))
    assert len(kept) >= 2
    # chunk files are not synced to disk: one a machine crash damaged is computed again, a
    # truncated one at once, one whose bytes changed once its checksum fails (the build
    # stops with one line; the same command again finishes it)
    with open(kept[0], "r+b") as fh:
        fh.truncate(100)
    with open(kept[1], "rb") as fh:
        head, base = chunkfile._header(fh)
    data = bytearray(kept[1].read_bytes())
    data[base + head["arrays"]["rejected"][2]] ^= 0x40  # a count of rejected edges
    kept[1].write_bytes(bytes(data))
    r = cli(*args)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-3000:]
    assert "was damaged" in r.stderr.strip().splitlines()[-1] and "rerun the same command" in r.stderr
    assert f"kept {partial}: run the same command to resume, or remove it" in r.stderr  # a failed build's chunks
    assert not kept[1].exists() and not out.exists() and not list(partial.glob("*.tmp"))
    assert "resuming the build kept in" in cli(*args).ok().stderr  # the resumed run says so
    assert same_datasets(tiny_map, out) == []
    assert attributes(tiny_map) == attributes(out)
    assert not partial.exists()


def test_ctrl_c_leaves_nothing_at_out_and_the_chunks_for_later(tmp_path):
    out = tmp_path / "map.h5"
    p = cli_process(*BUILD, "--edges", "200000", "--chunk", CHUNK, "--out", out)
    partial = Path(str(out) + ".partial")
    err = Collected(p.stderr)
    wait_for(lambda: bool(list(partial.glob("edges-*.chunk"))), p, "a saved chunk")
    p.send_signal(signal.SIGINT)
    p.wait(timeout=120)
    text = err.finish()
    assert p.returncode == 130 and "Traceback" not in text and "rerun the same command" in text, text
    assert "it resumes where this one stopped" in text, text
    assert not out.exists() and partial.is_dir()


def test_other_parameters_do_not_touch_a_partial_build(tmp_path):
    out = tmp_path / "map.h5"
    partial = Path(str(out) + ".partial")
    partial.mkdir()
    (partial / "plan.json").write_text(json.dumps({"edges": "something else"}))
    r = cli(*BUILD, "--out", out)
    assert r.returncode == 2 and "other parameters" in r.stderr.strip().splitlines()[-1] and "Traceback" not in r.stderr


def test_preflight_refuses_days_of_work_without_yes_and_missing_room(robot, tmp_path, monkeypatch):
    monkeypatch.setenv("LMJX_CORES", "1")  # 50,000,000 edges: about 21 h on two cores, 41 h on one
    r = cli("build-map", "--failure", "case2", "--edges", "50000000", "--out", tmp_path / "big.h5")
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert lines[0].startswith("preflight: 50,000,000 edges") and "--yes" in lines[-1], r.stderr
    assert not list(tmp_path.iterdir())
    pre = preflight(50_000_000, tmp_path / "big.h5", 1, "cpu")
    assert pre.seconds > 86_400 and pre.map_bytes > 20e9 and pre.disk_bytes > pre.map_bytes
    # no room: stops before any work
    import shutil

    from lmjx.edges.stream import build_map
    from lmjx.errors import ConfigError, OutputPathError
    from lmjx.model.failure import parse_failure

    def build(edges: int) -> None:
        build_map(tmp_path / "m.h5", parse_failure("case2", robot), ReachConfig(), BundleConfig(edges=edges), robot,
                  progress=False, say=lambda line: None)  # fmt: skip

    def free(n: int):
        return lambda path: shutil._ntuple_diskusage(10**15, 10**15 - n, n)

    # the CLI run above meets one refusal or both, depending on this disk; here each on its own, then both
    monkeypatch.setattr(shutil, "disk_usage", free(10**15))
    with pytest.raises(ConfigError, match="add --yes"):
        build(50_000_000)
    monkeypatch.setattr(shutil, "disk_usage", free(10**6))
    with pytest.raises(OutputPathError, match="not enough room") as info:
        build(100_000)
    assert "--yes" not in str(info.value)
    with pytest.raises(OutputPathError, match=r"not enough room.*add --yes"):
        build(50_000_000)
    assert not list(tmp_path.iterdir())


def test_packing_units_give_every_packer_work():
    from lmjx.edges.mapwriter import MIN_PACK_EDGES, PACK_EDGES, unit_edges

    assert unit_edges(100_000, 5) == 20_000  # a GPU's default build: one chunk, five units
    assert unit_edges(1_000_000, 5) == PACK_EDGES == 1 << 16
    assert unit_edges(10_000, 5) == MIN_PACK_EDGES and unit_edges(10, 1) == MIN_PACK_EDGES


def test_missing_ranges_cover_what_is_not_saved():
    assert missing_ranges([], 10, 4) == [(0, 4), (4, 8), (8, 10)]
    assert missing_ranges([(0, 3), (5, 7)], 10, 4) == [(3, 5), (7, 10)]
    assert missing_ranges([(0, 10)], 10, 4) == []


def test_two_devices_and_two_processes_build_the_same_file(tiny_map, tmp_path):
    """The datasets of the one-device build from one process with 2 host devices (each
    device whole chunks of its own, with its own programs and threads: exactly) and from 2
    processes of one device each (every launch split over both by programs XLA partitions,
    which may round differently in the last bit: the same edges, index, counts and push
    counts exactly, the states and their per-edge figures to float32 rounding)."""
    build = [*BUILD, "--chunk", CHUNK]
    two = tmp_path / "two.h5"
    p2 = cli_process(*build, "--out", two, "--json", env={"XLA_FLAGS": "--xla_force_host_platform_device_count=2"})
    with socket.socket() as sk:
        sk.bind(("127.0.0.1", 0))
        port = sk.getsockname()[1]
    common = [*build, "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2", "--json"]
    procs = [cli_process(*common, "--out", tmp_path / f"p{i}.h5", "--process-id", i) for i in range(2)]
    r2 = finish(p2, 900).ok()
    assert json.loads(r2.stdout)["devices"] == 2
    assert same_datasets(tiny_map, two) == []
    runs = [finish(p, 900) for p in procs]
    assert all(r.returncode == 0 for r in runs), [r.stderr[-2000:] for r in runs]
    text = runs[0].stdout
    assert json.loads(text[text.index("{\n") :])["processes"] == 2
    # (the push counts' names hash the edges' starts, which may differ in the last bit)
    assert same_datasets(tiny_map, tmp_path / "p0.h5", last_bit=COMPUTED, skip=PUSH_KEYS) == []
    assert not (tmp_path / "p1.h5").exists()  # only process 0 writes


def test_a_lazily_opened_map_decides_as_a_map_read_whole(robot, plan_map):
    """The planner on a map whose states stay in the file (read on demand) makes the same
    Greedy decisions as on the map read into memory; `lmjx info` reads no states."""
    from lmjx.mapfile.lazystates import StateReader
    from lmjx.planner.edge_planner import Planner
    from lmjx.sim.cpu import CpuSimulator
    from lmjx.sim.scenarios import sample_layout, scenario
    from lmjx.sim.scene import build_scene, object_qpos
    from lmjx.types import Observation, PlannerConfig

    whole, lazy = load_map(plan_map, robot, lazy=False), load_map(plan_map, robot, lazy=True)
    assert isinstance(whole.edges.q, np.ndarray) and isinstance(lazy.edges.q, StateReader) and lazy.edges.q.fast
    sc = scenario(1, tasks="hard")
    scene = build_scene(robot, sc)
    sim = CpuSimulator(scene)
    cfg = PlannerConfig(asm="greedy", greedy_candidates=6)
    pw = Planner(robot, whole.failure, whole.reach, whole.edges, sc, sim, cfg)
    pl = Planner(robot, lazy.failure, lazy.reach, lazy.edges, sc, sim, cfg)
    decided = 0
    for seed in range(3):
        obs = Observation(pw.transits.park, object_qpos(scene, sample_layout(sc, seed).poses), 0.0)
        a, ra = pw.choose(obs, np.random.default_rng(seed))
        b, rb = pl.choose(obs, np.random.default_rng(seed))
        assert (a is None) == (b is None)
        if a is not None:
            assert a.edge == b.edge and np.array_equal(a.q, b.q) and ra.predicted_distance == rb.predicted_distance
            decided += 1
    assert decided >= 2
    lazy.close()
    out = cli("info", plan_map, "--json").ok().stdout
    assert json.loads(out)["edges"]["valid"] == whole.edges.n_edges


def test_the_map_writing_process_reports_why_it_stopped(robot, small_map, tmp_path):
    """lmjx.edges.mapwriter: an error in the writing process reaches the build with its message
    (and its traceback there); a writing process killed outright stops the build too, at
    any point, never a hang."""
    from lmjx.edges.mapwriter import MapWriter

    reach = load_map(small_map, robot).reach
    config = BundleConfig(edges=1500, seed=1)
    kernels = {"compile_seconds": 0.0, "rollout_seconds": 0.0, "rollout_timing": {}, "rollout_copied_bytes": 0,
               "ik_seconds": 0.0}  # fmt: skip
    # a message it does not expect
    (tmp_path / "a").mkdir()
    w = MapWriter(tmp_path / "a", reach, config, robot, 1500, [], [(0, 1500)])
    assert w.job_sent.wait(60)  # (the feeder hands the job over first)
    w.to_writer.send(("bogus",))
    w.proc.wait(timeout=120)
    with pytest.raises(RuntimeError, match="got 'bogus' before every chunk") as info:
        w._check()
    assert "in the map-writing process" in "".join(getattr(info.value, "__notes__", []))
    w.abort()
    # killed while the build waits for the map (nothing left to compute)
    (tmp_path / "b").mkdir()
    w = MapWriter(tmp_path / "b", reach, config, robot, 1500, [], [])
    w.proc.kill()
    with pytest.raises(RuntimeError, match=r"map-writing process stopped \(exit code -9\)"):
        w.finish(tmp_path / "b.h5", kernels, 0.0, "cpu")
    w.abort()
    assert not (tmp_path / "b.h5").exists()


def test_the_index_is_assembled_from_the_chunks_as_a_sort_would(tmp_path, monkeypatch):
    """`mapappend.write_index_edges` places every chunk's (cell, edge) pairs without sorting: against
    a stable sort of all pairs by (cell, edge), over several cell ranges (a small
    INDEX_PAIRS), each placed in parts on several threads (a small PLACE_PAIRS), and chunks
    with cells absent, on random sorted unique pairs."""
    from lmjx.edges import mapappend
    from lmjx.edges.chunk import EdgeChunk

    rng = np.random.default_rng(7)
    n_cells, ranges, first, cells, edges = 50, [], [], [], []
    e0 = 0
    for k in range(5):
        n_edges = max(int(rng.integers(1, 40)), 35 if k == 4 else 1)
        pairs = np.unique(rng.integers(0, [n_cells, n_edges], size=(int(rng.integers(0, 300)), 2)), axis=0)
        if k == 2:
            pairs = pairs[pairs[:, 0] % 3 != 0]  # cells this chunk never reaches
        if k == 3:
            pairs = pairs[:0]  # a chunk without pairs
        if k == 4:  # a cell of more pairs than a part (PLACE_PAIRS below)
            pairs = np.unique(np.concatenate([pairs, np.stack([np.full(n_edges, 7), np.arange(n_edges)], 1)]), axis=0)
        arrays = {name: np.zeros(0, np.int32) for name in EdgeChunk.ARRAYS}
        arrays |= {"index_cell": pairs[:, 0].astype(np.int32), "index_edge": pairs[:, 1].astype(np.int32)}
        chunkfile.save(tmp_path, EdgeChunk(start=100 * k, stop=100 * k + 100, rolled_out=0, states_evaluated=0,
                                           **arrays))  # fmt: skip
        ranges.append((100 * k, 100 * k + 100))
        first.append(e0)
        cells.append(pairs[:, 0])
        edges.append(pairs[:, 1] + e0)
        e0 += n_edges
    cell, edge = np.concatenate(cells), np.concatenate(edges)
    want = edge[np.lexsort((edge, cell))]
    offset = np.zeros(n_cells + 1, np.int64)
    offset[1:] = np.cumsum(np.bincount(cell, minlength=n_cells))
    assert np.bincount(cell)[7] > 29 and len(cells[3]) == 0
    monkeypatch.setattr(mapappend, "INDEX_PAIRS", 97)  # read in ranges of cells ...
    for place in (29, 3):  # ... each placed in parts on the threads
        monkeypatch.setattr(mapappend, "PLACE_PAIRS", place)
        with h5py.File(tmp_path / "index.h5", "w") as f:  # stored as a map's index (chunks of 64 here), read by HDF5
            ds = f.create_dataset("edges", (len(want),), np.int32, chunks=(64,), compression="gzip", shuffle=True,
                                  fletcher32=True)  # fmt: skip
            mapappend.write_index_edges(ds, tmp_path, ranges, first, offset, threads=3)
            assert len(want) % 64 and np.array_equal(ds[...], want)
    # counts that are not the chunks' pairs (one pair too few, or too many, in a cell) are refused
    for change in (1, -1):
        wrong = offset.copy()
        wrong[8:] += change
        with h5py.File(tmp_path / "wrong.h5", "w") as f:
            ds = f.create_dataset("edges", (int(wrong[-1]),), np.int32, chunks=(64,))
            with pytest.raises(RuntimeError, match="other index pairs than those counted"):
                mapappend.write_index_edges(ds, tmp_path, ranges, first, wrong, threads=3)


def test_the_writing_process_starts_light_and_ends_unused():
    """lmjx.edges.mapappend: the writing process's program imports neither JAX nor the robot's
    model (it starts while the build computes its reach map, and its first chunk must not wait
    for it); one never handed its job ends when the build's pipe closes, or when stopped."""
    import subprocess
    import sys

    from lmjx.edges.mapwriter import WriterProcess

    code = "import lmjx.edges.mapappend, sys; print([m for m in ('jax', 'mujoco', 'kernels') if m in sys.modules])"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == "[]"
    p = WriterProcess()
    p.to_writer.close()
    assert p.proc.wait(timeout=60) == 0
    p.stop()
    p = WriterProcess()
    p.stop()
    assert p.proc.returncode is not None
    p.stop()  # (again: nothing)


def test_a_peer_process_saves_the_chunks_and_push_counts_this_process_computes(tiny_map, tmp_path):
    """A build's peer process (`lmjx.edges.peers`: what a build on several GPUs runs each
    GPU but the first in), given chunks of the test arm's build, saves the units this process
    packs from the same chunks, array for array, and sends back their push counts summed, as
    this process sums them; a peer given no chunk is stopped without waiting for it."""
    import jax

    from lmjx.edges.chunk import chunk_ranges, pack_chunk
    from lmjx.edges.peers import PeerPrograms, Peers, PeerWork
    from lmjx.edges.sampling import EdgeKernels, draw_edges, roll_out, solve_starts, split_rolled
    from lmjx.mapfile.pushbuild import BuildPushCounts
    from lmjx.model.robot import load_robot

    robot = load_robot(str(TINY_ARM))
    m = load_map(tiny_map, robot)
    reach, config = m.reach, m.edges.config
    half = reach.config.object_height / 2
    chunks, unit = [(400, 800), (800, 1200)], 300  # (units that cut through chunks)
    folder = tmp_path / "peer"
    folder.mkdir()
    programs = PeerPrograms(str(TINY_ARM), reach.failure, config, half, reach.config.chunk,
                            (len(reach.xs), len(reach.ys), reach.config.cell), 0.005, "cpu")  # fmt: skip
    left, saved, errors = list(chunks), [], []
    with Peers([jax.local_devices()[0]] * 2, programs) as peers:
        peers.begin(PeerWork(reach, str(folder), unit, 2, True), lambda i: left.pop(0) if i == 0 and left else None,
                    lambda a, b: saved.append((a, b)), lambda i, e: errors.append(e))  # fmt: skip
        results = peers.finish(lambda i: i == 0)  # (peer 0 ends once it is told there is no chunk left)
    assert errors == [] and len(results) == 1 and results[0]["chunks"] == 2 and results[0]["edges"] == 800
    units = [u for a, b in chunks for u in chunk_ranges(b, unit, a)]
    assert sorted(saved) == units
    # the same chunks here: the same units, the same push counts
    kernels = EdgeKernels(robot, reach.failure, config, True, half, ik_chunk=reach.config.chunk)
    push = BuildPushCounts(robot, reach.failure, reach)
    for a, b in chunks:
        samples = solve_starts(draw_edges(reach, config, robot, a, b), kernels)
        idx, rolled = roll_out(samples, kernels)
        for ua, ub in chunk_ranges(b, unit, a):
            here = pack_chunk(reach, config, robot, *split_rolled(samples, idx, rolled, ua, ub))
            push.add(here.length, here.q)
            there = chunkfile.load(folder, ua, ub)
            for name in here.ARRAYS:
                np.testing.assert_array_equal(getattr(there, name), getattr(here, name), err_msg=name)
    assert results[0]["push"]["edges"] == push.edges > 0
    np.testing.assert_array_equal(results[0]["push"]["counts"], push.counts)
    assert push.counts.sum() > 0


def test_a_peer_that_fails_stops_the_build_with_its_own_error(tiny_map, tmp_path):
    """A peer process that cannot run (here: told its device is a GPU where it sees the host)
    ends with its own error, handed to the build (`failed`, `check`), not a closed pipe's."""
    import jax

    from lmjx.edges.peers import PeerPrograms, Peers, PeerWork
    from lmjx.model.robot import load_robot

    m = load_map(tiny_map, load_robot(str(TINY_ARM)), with_edges=False)
    reach = m.reach
    programs = PeerPrograms(str(TINY_ARM), reach.failure, BundleConfig(), 0.025, None, (2, 2, 0.1), 0.005, "gpu")
    errors = []
    with Peers([jax.local_devices()[0]], programs) as peers:
        peers.begin(PeerWork(reach, str(tmp_path), 300, 1, False), lambda i: None, lambda a, b: None,
                    lambda i, e: errors.append(e))  # fmt: skip
        with pytest.raises(RuntimeError, match="a peer process for the build's gpu device 0 sees"):
            peers.finish(lambda i: True)
    assert len(errors) == 1 and "sees" in str(errors[0])
