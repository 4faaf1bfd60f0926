"""Files a user cannot lose or misread, and numbers checked where they are given.

Map files carry HDF5's Fletcher-32 checksum on every numeric dataset, lmjx's own chunk
writing and reading included (checked against HDF5 itself); `lmjx info --verify` reads a
whole file and names every damaged part; a map or an MJCF at --out is replaced only with
--overwrite, and build-map keeps the map it would build again; a failed build leaves nothing
it cannot resume; every numeric option and the public functions' numbers are refused in
one line before any work or any file; `plan --strict` tells a failed task by its exit
status.  The maps are the run's shared ones (tests/conftest.py)."""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import TINY_ARM, TINY_MAP, cli

import lmjx
from lmjx.errors import ConfigError, MapFileError
from lmjx.mapfile.checksum import ChecksumError, fletcher32, strip_checksum, with_checksum
from lmjx.mapfile.lazystates import StateReader
from lmjx.mapfile.read import load_map
from lmjx.mapfile.verify import verify_map

# ------------------------------------------------------------------------------ checksums


def _hdf5_checksum(f: h5py.File, name: str, data: np.ndarray) -> int:
    """The Fletcher-32 HDF5 stores for `data` (bytes) as one chunk."""
    ds = f.create_dataset(name, data=data, chunks=(len(data),), fletcher32=True)
    raw = ds.id.read_direct_chunk((0,))[1]
    assert raw[:-4] == data.tobytes()
    return int.from_bytes(raw[-4:], "little")


def test_fletcher32_is_hdf5s(tmp_path):
    """lmjx's Fletcher-32 against HDF5's own, byte for byte, over odd and even lengths, the
    block boundaries of HDF5's loop (360 words), all-0xff (its largest sums), all-zero, and
    sums that are multiples of 65535; HDF5 reads back a chunk checksummed by lmjx and refuses
    it once a byte changes, as lmjx does."""
    rng = np.random.default_rng(0)
    cases = [np.frombuffer(np.array(w, ">u2").tobytes(), np.uint8) for w in ([65535], [1, 65534], [0, 0, 65535])]
    for n in (1, 2, 3, 719, 720, 721, 722, 1441, 65535, 65536, 300_001, 2 * 2**20 + 3):
        cases += [rng.integers(0, 256, n).astype(np.uint8), np.full(n, 255, np.uint8), np.zeros(n, np.uint8)]
    with h5py.File(tmp_path / "f.h5", "w") as f:
        for i, data in enumerate(cases):
            assert fletcher32(data.tobytes()) == _hdf5_checksum(f, str(i), data), (i, len(data))
        data = rng.integers(0, 256, 4001).astype(np.uint8)
        ds = f.create_dataset("mine", shape=data.shape, dtype=np.uint8, chunks=data.shape, fletcher32=True)
        ds.id.write_direct_chunk((0,), with_checksum(data.tobytes()), 0)
        assert np.array_equal(ds[...], data)
        bad = bytearray(with_checksum(data.tobytes()))
        bad[2000] ^= 1
        ds.id.write_direct_chunk((0,), bytes(bad), 0)
        with pytest.raises(OSError):
            ds[...]
    with pytest.raises(ChecksumError, match="fails its checksum"):
        strip_checksum(bytes(bad))
    assert bytes(strip_checksum(with_checksum(b"abc"))) == b"abc"


def test_lmjx_chunks_are_hdf5s(tmp_path, monkeypatch):
    """The states' chunks lmjx compresses itself are the bytes HDF5's shuffle, deflate and
    Fletcher-32 filters store for the same rows (with the same deflate: zlib), the last chunk
    zero-padded as HDF5 pads it; the lazy reader checks them, and a damaged one is a one-line
    MapFileError there and an error in h5py."""
    import lmjx.mapfile.write as write

    monkeypatch.setattr(write, "_deflate", zlib)
    rng = np.random.default_rng(1)
    rows, n = 1000, 2 * 1000 + 123
    data = rng.normal(size=(n, 7)).astype(np.float32)
    kw = dict(shape=(n, 7), dtype=np.float32, chunks=(rows, 7), compression="gzip", compression_opts=1,
              shuffle=True, fletcher32=True)  # fmt: skip
    with h5py.File(tmp_path / "s.h5", "w") as f:
        by_hdf5, by_lmjx = f.create_dataset("hdf5", **kw), f.create_dataset("lmjx", **kw)
        by_hdf5[...] = data
        write._write_chunks(by_lmjx, [(r, [data[r : r + 7], data[r + 7 : r + rows]]) for r in range(0, n, rows)],
                            rows, by_lmjx.dtype)  # fmt: skip
        for r in range(0, n, rows):
            assert by_lmjx.id.read_direct_chunk((r, 0)) == by_hdf5.id.read_direct_chunk((r, 0)), r
        reader = StateReader(by_lmjx, threads=2)
        assert reader.fast and reader.checked
        reader.prefetch([(0, n)])
        np.testing.assert_array_equal(reader[995:1010], data[995:1010])
        reader.close()
        _, raw = by_lmjx.id.read_direct_chunk((rows, 0))
        damaged = bytearray(raw)
        damaged[len(raw) // 2] ^= 0x10
        by_lmjx.id.write_direct_chunk((rows, 0), bytes(damaged), 0)
        reader = StateReader(by_lmjx, threads=1)
        np.testing.assert_array_equal(reader[0:5], data[0:5])  # the chunk before is whole
        with pytest.raises(MapFileError, match=r"/lmjx is damaged \(rows 1,000 to 1,999: chunk fails its checksum"):
            reader[1500:1501]
        reader.close()
        with pytest.raises(OSError):
            by_lmjx[1500]


# ------------------------------------------------------------------------------ info --verify


def _numeric_datasets(path: Path) -> list[str]:
    names: list[str] = []
    with h5py.File(path, "r") as f:
        f.visititems(lambda k, o: names.append(k) if isinstance(o, h5py.Dataset) and o.dtype.kind != "O" else None)
    return names


def test_a_whole_map_verifies_with_a_checksum_on_every_numeric_dataset(tiny_map):
    v = verify_map(tiny_map)
    assert v.problems == [] and v.unchecked == [] and v.chunks >= v.checksummed > 0
    assert v.checksummed == len(_numeric_datasets(tiny_map))  # text (the MJCF, names) takes no filter
    r = cli("info", tiny_map, "--robot", TINY_ARM, "--verify", "--json").ok()
    assert json.loads(r.stdout)["verified"]["problems"] == []


def test_random_bytes_in_the_middle_of_a_map_are_found(tiny_map, tmp_path):
    """4 KB of random bytes written into the middle of a map: `info --verify` names the
    damaged dataset and exits 1; reading that part (load_map, or the lazy reader for the
    states) is a one-line MapFileError; a plain `info`, which reads no states, says where
    to look."""
    bad = tmp_path / "bad.h5"
    shutil.copy(tiny_map, bad)
    middle = bad.stat().st_size // 2
    hit = []
    with h5py.File(bad, "r") as f:

        def chunks(name: str, obj: object) -> None:
            if isinstance(obj, h5py.Dataset) and obj.chunks:
                obj.id.chunk_iter(lambda c: hit.append(name) if c.byte_offset < middle + 4096 and
                                  c.byte_offset + c.size > middle else None)  # fmt: skip

        f.visititems(chunks)
    assert hit and all(n in _numeric_datasets(bad) for n in hit), hit  # the 4 KB fall in checksummed data
    with open(bad, "r+b") as fh:
        fh.seek(middle)
        fh.write(np.random.default_rng(7).bytes(4096))
    r = cli("info", bad, "--robot", TINY_ARM, "--verify")
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and r.stdout == "" and "Traceback" not in r.stderr, r.stderr
    assert all(line.startswith(f"lmjx info: {bad}: ") for line in lines)
    assert {line.split(": ")[2] for line in lines} == set(hit) and "fails its checksum" in lines[0], lines
    with pytest.raises(MapFileError, match=f"/{hit[0]} is damaged") as e:
        load_map(bad, TINY_ARM, lazy=False)
    assert "\n" not in str(e.value)
    if hit[0] in ("edges/q", "edges/qd", "edges/p"):
        plain = cli("info", bad, "--robot", TINY_ARM).ok()
        assert "--verify" in plain.stdout
        with load_map(bad, TINY_ARM, lazy=True) as m, pytest.raises(MapFileError, match="fails its checksum"):
            getattr(m.edges, hit[0].split("/")[1])[0 : len(m.edges.q)]


def test_verify_checks_the_arrays_against_each_other(tiny_map, tmp_path):
    """Values rewritten through HDF5 (their checksums right): the offsets, the index's edge
    ids and an area attribute that no longer agree are each one line."""
    bad = tmp_path / "inconsistent.h5"
    shutil.copy(tiny_map, bad)
    with h5py.File(bad, "r+") as f:
        f["edges/offset"][1] += 1
        f["edges/index/edges"][0] = 10**6
        f["reach"].attrs["area_pm_m2"] = 123.0
    problems = verify_map(bad).problems
    assert len(problems) == 3, problems
    assert problems[0].startswith("/reach: area_pm_m2 123 does not match labels_smooth")
    assert problems[1].startswith("edges/offset, edges/length: an edge's rows do not follow")
    assert problems[2].startswith("edges/index/edges: an edge id outside")
    cli("info", tmp_path / "none.h5", "--verify").one_line_error("does not exist")


# ------------------------------------------------------------------------------ --out, --overwrite


def test_maps_and_robots_at_out_are_replaced_only_with_overwrite(tiny_map, tmp_path):
    """reach --out and robot import --out onto an existing file: refused in one line naming
    --overwrite, before any work, the file untouched; with --overwrite, replaced."""
    there = tmp_path / "map.h5"
    shutil.copy(tiny_map, there)
    before = there.read_bytes()
    cli("reach", "--failure", "case1", "--cell", "0.1", "--out", there).one_line_error("add --overwrite")
    xml = tmp_path / "arm.xml"
    xml.write_text("<mujoco/>")
    cli("robot", "import", tmp_path / "src.urdf", "--out", xml, "--qdd-max", "5").one_line_error("add --overwrite")
    assert there.read_bytes() == before and xml.read_text() == "<mujoco/>"
    cli("reach", "--failure", "case1", "--cell", "0.1", "--out", there, "--overwrite").ok()
    with load_map(there) as m:
        assert m.failure.spec == "case1" and m.edges is None


def test_build_map_run_twice_keeps_its_map_and_refuses_another(tiny_map, tmp_path):
    """`make run` a second time: the same command keeps the map (exit 0, nothing computed,
    the file untouched); other parameters are refused in one line naming --overwrite;
    --overwrite builds it again, to the same datasets."""
    from test_edgestream import same_datasets

    out = tmp_path / "tiny.h5"
    shutil.copy(tiny_map, out)
    stamp = out.stat().st_mtime_ns
    r = cli("build-map", *TINY_MAP, "--out", out).ok()
    assert "already holds this map" in r.stdout and "--overwrite" in r.stdout and r.stderr == "", r.stderr
    s = json.loads(cli("build-map", *TINY_MAP, "--out", out, "--json").ok().stdout)
    assert s["built"] is False and s["edges"]["edges_valid"] > 0
    other = list(TINY_MAP)
    other[other.index("--seed") + 1] = "4"
    cli("build-map", *other, "--out", out).one_line_error("built with reach seed 3, not 4; add --overwrite")
    cli("build-map", "--failure", "case2", "--out", out).one_line_error("a map of another robot")
    reach_only = tmp_path / "reach.h5"
    shutil.copy(tiny_map, reach_only)
    with h5py.File(reach_only, "a") as f:
        del f["edges"]
        f.attrs["contents"] = "reach"
    cli("build-map", *TINY_MAP, "--out", reach_only).one_line_error("a map without edges (lmjx reach --out)")
    assert out.stat().st_mtime_ns == stamp and not list(tmp_path.glob("*.partial"))
    with pytest.raises(lmjx.LmjxError, match="add --overwrite"):
        lmjx.build_map("J4=0.5", robot=TINY_ARM, out=out, edges=1200, cell=0.05, seed=4)
    r = cli("build-map", *TINY_MAP, "--out", out, "--overwrite").ok()
    assert "map written to" in r.stdout and out.stat().st_mtime_ns != stamp
    assert same_datasets(tiny_map, out) == []


def test_a_failed_build_leaves_nothing(tmp_path):
    """The four-joint arm with its shoulder and elbow locked folded up reaches no cell: the
    build stops after the reach map in one line, and leaves neither the map nor the partial
    folder nor a temporary file (a process of its own, as a user runs it: it leaves at once,
    not compiling the edges' programs first)."""
    out = tmp_path / "folded.h5"
    r = subprocess.run([sys.executable, "-m", "lmjx.cli", "build-map", "--robot", str(TINY_ARM), "--failure",
                        "J2=1.8,J3=2.6", "--cell", "0.2", "--edges", "100", "--out", str(out)],
                       capture_output=True, text=True, timeout=600)  # fmt: skip
    errors = [line for line in r.stderr.splitlines() if "error" in line]
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert errors == ["lmjx build-map: error: failure J2=1.8,J3=2.6: no reachable cell on the task plane, so no edge "
                      "can start"], r.stderr  # fmt: skip
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------ numbers at the boundary


def _options(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()):
    """(command words, action) of every option of every command."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _options(sub, (*prefix, name))
        elif action.option_strings:
            yield prefix, action


def test_every_numeric_option_is_checked_by_its_parser():
    """No option reads a number unchecked (type=int or float): every one refuses -1, NaN,
    infinity and text in one line naming the option, before the command runs (argparse
    stops at the first bad value)."""
    from lmjx.cli import build_parser

    numeric = [(words, a) for words, a in _options(build_parser()) if a.type is not None and a.choices is None]
    assert len(numeric) > 40
    for words, action in numeric:
        assert action.type not in (int, float), (words, action.option_strings)
        option = action.option_strings[-1]
        for bad in ("nan", "inf", "1e999", "x", "-1"):
            cli(*words, option, bad).one_line_error(f"argument {option}")


@pytest.mark.parametrize(
    "args, message",
    [
        (["reach", "--failure", "case2", "--seed", "-1"], "argument --seed: must be at least 0"),
        (["reach", "--failure", "case2", "--seed", "4294967296"], "must be at most 4294967295"),
        (["reach", "--failure", "case2", "--attempts", "200"], "attempts (k) must be 2 to 128"),
        (["build-map", "--failure", "case2", "--seed", "-1"], "argument --seed"),
        (["build-map", "--failure", "case2", "--process-id", "1"], "--process-id 1: ranks are 0 to 0"),
        (["plan", "--map", "m.h5", "--scenario", "1", "--asm", "random", "--seed", "-1"], "argument --seed"),
        (["evaluate", "--out", "ev", "--seed", "-1"], "argument --seed"),
        (["evaluate", "--out", "ev", "--seed", "42950"], "must be at most 42949"),
        (["evaluate", "--out", "ev", "--trials", "1001"], "must be at most 1000"),
        (["scenarios", "--out", "pics", "--seed", "-1"], "argument --seed"),
        (["scenarios", "--out", "pics", "--robot", "nowhere.xml"], "nowhere.xml"),
        (["evaluate", "--out", "ev", "--maps", "nomaps"], "nomaps"),
        (["view", "m.h5", "--at", "nan"], "argument --at"),
        (["bench", "--candidates", "8,0"], "argument --candidates"),
        (["robot", "import", "a.urdf", "--out", "a.xml", "--limit", "-3"], "argument --limit"),
    ],
)
def test_bad_numbers_leave_no_file_or_folder(args, message, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cli(*args).one_line_error(message)
    assert list(tmp_path.iterdir()) == []


def test_evaluate_makes_its_folder_once_everything_is_checked(small_map, tmp_path):
    """A simulator that cannot run here is refused after the maps are read, before --out is made."""
    from lmjx.planner.trial import resolve_simulator

    try:
        resolve_simulator("gpu")
        pytest.skip("this machine runs the GPU simulator")
    except ConfigError:
        pass
    out = tmp_path / "eval"
    r = cli("evaluate", "--failures", "case2", "--scenarios", "1", "--asms", "greedy", "--trials", "1", "--sim", "gpu",
            "--maps", small_map.parent, "--out", out)  # fmt: skip
    assert r.returncode == 2 and "Traceback" not in r.stderr and not out.exists(), r.stderr


def test_public_functions_refuse_bad_numbers_in_one_line(tmp_path):
    for call, message in (
        (lambda: lmjx.plan_task(tmp_path / "m.h5", 1, "random", seed=-1), "seed must be at least 0"),
        (lambda: lmjx.plan_task(tmp_path / "m.h5", 1, "random", seed=2**40), "seed must be at most"),
        (lambda: lmjx.plan_task(tmp_path / "m.h5", 1, "random", seed=1.5), "seed must be a whole number"),
        (lambda: lmjx.plan_task(tmp_path / "m.h5", 1, "random", max_actions=0), "max_actions must be at least 1"),
        (lambda: lmjx.build_map("case2", out=tmp_path / "m.h5", seed=-1), "seed must be at least 0"),
        (lambda: lmjx.build_map("case2", out=tmp_path / "m.h5", cell=float("nan")), "cell must be a finite number"),
        (lambda: lmjx.build_map("case2", out=tmp_path / "m.h5", edges=0), "edges must be at least 1"),
        (lambda: lmjx.reach_map("case2", lmjx.ReachConfig(seed=-3)), "seed must be at least 0"),
    ):
        with pytest.raises(ConfigError, match=message) as e:
            call()
        assert "\n" not in str(e.value)
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------ plan --strict


def test_plan_strict_exit_status_tells_a_failed_task(small_map):
    """One random action in the tunnel scenario does not reach the goal: exit 3 with
    --strict (the same task printed), 0 without."""
    args = ("plan", "--map", small_map, "--scenario", "2", "--asm", "random", "--max-actions", "1", "--json")
    plain = json.loads(cli(*args).ok().stdout)
    strict = cli(*args, "--strict")
    assert strict.returncode == 3 and "Traceback" not in strict.stderr, strict.stderr
    again = json.loads(strict.stdout)
    assert plain["success"] is again["success"] is False and plain["steps"][0]["edge"] == again["steps"][0]["edge"]
    assert "exit with status 3" in cli("plan", "--help").stdout
