"""Maps of any size (lmjx.edgestream): streamed builds give the in-memory bundle's datasets
for any chunk size, any number of devices and processes; a killed build resumes to the
uninterrupted file; the preflight refuses what cannot fit or would take days; a map opened
lazily makes the planner's decisions a map read whole makes."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from lmjx import chunkfile
from lmjx.bundle import BundleConfig, build_bundle
from lmjx.edgestream import missing_ranges, preflight
from lmjx.mapfile import load_map, write_map
from lmjx.reach import ReachConfig, reach_map

SMALL = ["--failure", "case2", "--edges", "1500", "--cell", "0.05", "--seed", "1"]


def _lmjx(args, env=None):
    e = dict(os.environ, JAX_PLATFORMS="cpu")
    e.update(env or {})
    return subprocess.Popen([sys.executable, "-m", "lmjx.cli", *args], env=e, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip


def _run(args, env=None, timeout=900):
    p = _lmjx(args, env)
    out, err = p.communicate(timeout=timeout)
    assert p.returncode == 0, err[-3000:]
    return out, err


def datasets(path) -> dict[str, np.ndarray]:
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[...]) if isinstance(obj, h5py.Dataset) else None)
    return out


def same_datasets(a, b) -> list[str]:
    da, db = datasets(a), datasets(b)
    return [k for k in sorted(set(da) | set(db)) if k not in da or k not in db
            or not np.array_equal(da[k], db[k], equal_nan=da[k].dtype.kind == "f")]  # fmt: skip


@pytest.fixture(scope="module")
def streamed(tmp_path_factory):
    """The small map streamed in chunks of 400 edges."""
    path = tmp_path_factory.mktemp("stream") / "a.h5"
    _run(["build-map", *SMALL, "--chunk", "400", "--out", str(path)],
         env={"LMJX_THREAD_PROFILE": str(path.with_name("threads.json"))})  # fmt: skip
    return path


def test_a_build_reports_where_its_threads_are(streamed):
    """LMJX_THREAD_PROFILE: the sampled threads of the build, grouped, each with its places."""
    groups = json.loads(streamed.with_name("threads.json").read_text())["groups"]
    assert {"MainThread", "lmjx-chunk", "lmjx-map-feed", "lmjx-pack"} <= set(groups)
    assert {"writer/lmjx-map-writer", "writer/lmjx-write", "writer/lmjx-read"} <= set(groups)  # lmjx.mapwriter
    chunk = [where for where, _ in groups["lmjx-chunk"]["top"]]
    assert any(w.split(":")[0] in ("batching.py", "bundle.py", "edgestream.py", "ik_batch.py") for w in chunk)


def test_chunk_size_and_memory_do_not_change_the_datasets(robot, streamed, tmp_path):
    other = tmp_path / "b.h5"
    # computed in chunks of 1100, packed in units of 300 (lmjx.mapwriter.PACK_EDGES), in a
    # process of its own while this one builds the bundle in memory
    p = _lmjx(["build-map", *SMALL, "--chunk", "1100", "--out", str(other)], env={"LMJX_PACK_EDGES": "300"})
    # the in-memory bundle (lmjx.bundle.build_bundle, in chunks of 250) writes the same datasets
    reach = reach_map("case2", ReachConfig(cell=0.05, seed=1), robot=robot)
    bundle = build_bundle(reach, BundleConfig(edges=1500, seed=1, build_chunk=250), robot=robot)
    whole = tmp_path / "whole.h5"
    write_map(whole, reach, bundle, robot)
    assert same_datasets(streamed, whole) == []
    _, err = p.communicate(timeout=900)
    assert p.returncode == 0, err[-3000:]
    assert "preflight:" in err
    assert same_datasets(streamed, other) == []
    assert not Path(str(other) + ".partial").exists() and bundle.n_edges > 100


def test_killed_build_resumes_to_the_uninterrupted_file(streamed, tmp_path):
    out = tmp_path / "resumed.h5"
    partial = Path(str(out) + ".partial")
    p = _lmjx(["build-map", *SMALL, "--chunk", "150", "--out", str(out)])
    t0 = time.time()
    while p.poll() is None and time.time() - t0 < 600:
        if partial.is_dir() and len(list(partial.glob("edges-*.chunk"))) >= 2:
            break
        time.sleep(0.05)
    p.send_signal(signal.SIGKILL)
    p.communicate(timeout=60)
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
    p = _lmjx(["build-map", *SMALL, "--chunk", "150", "--out", str(out)])
    _, err = p.communicate(timeout=900)
    assert p.returncode == 2 and "Traceback" not in err, err[-3000:]
    assert "was damaged" in err.strip().splitlines()[-1] and "rerun the same command" in err
    assert not kept[1].exists() and not out.exists()
    _, _err = _run(["build-map", *SMALL, "--chunk", "150", "--out", str(out)])
    assert same_datasets(streamed, out) == []
    assert not partial.exists()


def test_ctrl_c_leaves_nothing_at_out_and_the_chunks_for_later(tmp_path):
    out = tmp_path / "map.h5"
    p = _lmjx(["build-map", *SMALL, "--edges", "200000", "--chunk", "300", "--out", str(out)])
    partial = Path(str(out) + ".partial")
    t0 = time.time()
    while p.poll() is None and time.time() - t0 < 600 and not list(partial.glob("edges-*.chunk")):
        time.sleep(0.05)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130 and "Traceback" not in err and "rerun the same command" in err
    assert not out.exists() and partial.is_dir()


def test_other_parameters_do_not_touch_a_partial_build(tmp_path):
    out = tmp_path / "map.h5"
    partial = Path(str(out) + ".partial")
    partial.mkdir()
    (partial / "plan.json").write_text(json.dumps({"edges": "something else"}))
    p = _lmjx(["build-map", *SMALL, "--out", str(out)])
    _, err = p.communicate(timeout=300)
    assert p.returncode == 2 and "other parameters" in err.strip().splitlines()[-1] and "Traceback" not in err


def test_preflight_refuses_days_of_work_without_yes_and_missing_room(tmp_path, monkeypatch):
    p = _lmjx(["build-map", "--failure", "case2", "--edges", "50000000", "--out", str(tmp_path / "big.h5")])
    _, err = p.communicate(timeout=300)
    lines = err.strip().splitlines()
    assert p.returncode == 2 and "Traceback" not in err
    assert lines[0].startswith("preflight: 50,000,000 edges") and "--yes" in lines[-1], err
    assert not list(tmp_path.iterdir())
    pre = preflight(50_000_000, tmp_path / "big.h5", 1, "cpu")
    assert pre.seconds > 86_400 and pre.map_bytes > 20e9 and pre.disk_bytes > pre.map_bytes
    # no room: stops before any work
    import shutil

    from lmjx.edgestream import build_map
    from lmjx.errors import ConfigError, OutputPathError
    from lmjx.failure import parse_failure
    from lmjx.robot import load_robot

    robot = load_robot()

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


def test_missing_ranges_cover_what_is_not_saved():
    assert missing_ranges([], 10, 4) == [(0, 4), (4, 8), (8, 10)]
    assert missing_ranges([(0, 3), (5, 7)], 10, 4) == [(3, 5), (7, 10)]
    assert missing_ranges([(0, 10)], 10, 4) == []


def test_four_devices_and_two_processes_build_the_same_file(streamed, tmp_path):
    # the three runs at once: one process with 4 host devices, and 2 processes of one device each
    four = tmp_path / "four.h5"
    p4 = _lmjx(["build-map", *SMALL, "--out", str(four), "--json"],
               env={"XLA_FLAGS": "--xla_force_host_platform_device_count=4"})  # fmt: skip
    with socket.socket() as sk:
        sk.bind(("127.0.0.1", 0))
        port = sk.getsockname()[1]
    common = ["build-map", *SMALL, "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2", "--json"]
    procs = [_lmjx([*common, "--out", str(tmp_path / f"p{i}.h5"), "--process-id", str(i)]) for i in range(2)]
    out, err = p4.communicate(timeout=900)
    assert p4.returncode == 0, err[-3000:]
    assert json.loads(out)["devices"] == 4
    assert same_datasets(streamed, four) == []
    outs = [p.communicate(timeout=900) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1][-2000:] for o in outs]
    text = outs[0][0]
    assert json.loads(text[text.index("{\n") :])["processes"] == 2
    assert same_datasets(streamed, tmp_path / "p0.h5") == []
    assert not (tmp_path / "p1.h5").exists()  # only process 0 writes


def test_a_lazily_opened_map_decides_as_a_map_read_whole(robot, streamed):
    """The planner on a map whose states stay in the file (read on demand) makes the same
    Greedy decisions as on the map read into memory; `lmjx info` reads no states."""
    from lmjx.executor import Observation
    from lmjx.lazystates import StateReader
    from lmjx.planner import Planner, PlannerConfig
    from lmjx.scenarios import sample_layout, scenario
    from lmjx.scene import build_scene, object_qpos
    from lmjx.simulate import CpuSimulator

    whole, lazy = load_map(streamed, robot, lazy=False), load_map(streamed, robot, lazy=True)
    assert isinstance(whole.edges.q, np.ndarray) and isinstance(lazy.edges.q, StateReader) and lazy.edges.q.fast
    sc = scenario(3)
    scene = build_scene(robot, sc)
    sim = CpuSimulator(scene)
    cfg = PlannerConfig(asm="greedy", greedy_candidates=6)
    pw = Planner(robot, whole.failure, whole.reach, whole.edges, sc, sim, cfg)
    pl = Planner(robot, lazy.failure, lazy.reach, lazy.edges, sc, sim, cfg)
    decided = 0
    for seed in range(4):
        obs = Observation(pw.transits.park, object_qpos(scene, sample_layout(sc, seed).poses), 0.0)
        a, ra = pw.choose(obs, np.random.default_rng(seed))
        b, rb = pl.choose(obs, np.random.default_rng(seed))
        assert (a is None) == (b is None)
        if a is not None:
            assert a.edge == b.edge and np.array_equal(a.q, b.q) and ra.predicted_distance == rb.predicted_distance
            decided += 1
    assert decided >= 2
    lazy.close()
    out, _ = _run(["info", str(streamed), "--json"])
    assert json.loads(out)["edges"]["valid"] == whole.edges.n_edges


def test_the_map_writing_process_reports_why_it_stopped(robot, tmp_path):
    """lmjx.mapwriter: an error in the writing process reaches the build with its message
    (and its traceback there); a writing process killed outright stops the build too, at
    any point, never a hang."""
    from lmjx.mapwriter import MapWriter

    reach = reach_map("case2", ReachConfig(cell=0.05, seed=1), robot=robot)
    config = BundleConfig(edges=1500, seed=1)
    kernels = {"compile_seconds": 0.0, "rollout_seconds": 0.0, "rollout_timing": {}, "rollout_copied_bytes": 0,
               "ik_seconds": 0.0}  # fmt: skip
    # a message it does not expect
    (tmp_path / "a").mkdir()
    w = MapWriter(tmp_path / "a", reach, config, robot, 1500, [], [(0, 1500)])
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
