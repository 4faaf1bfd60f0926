"""Map files: round trip, plain-h5py reading by the documented schema, validation errors."""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

from lmjx.errors import MapFileError
from lmjx.mapfile import load_map, write_reach_map
from lmjx.reach import ReachConfig, reach_map


@pytest.fixture(scope="module")
def small_map(robot, tmp_path_factory):
    res = reach_map("case1", ReachConfig(cell=0.1), robot=robot)
    path = tmp_path_factory.mktemp("maps") / "case1.h5"
    write_reach_map(path, res, robot)
    return res, path


def test_round_trip(small_map):
    res, path = small_map
    m = load_map(path)
    assert m.failure.spec == res.failure.spec and m.failure.locked == res.failure.locked
    r = m.reach
    assert r.config == res.config
    for k in ("xs", "ys", "labels", "labels_smooth", "attempt", "site"):
        assert np.array_equal(getattr(r, k), getattr(res, k)), k
    for k in ("q", "target", "pos_err"):
        assert np.array_equal(getattr(r, k), getattr(res, k), equal_nan=True), k
    assert r.areas() == res.areas()


def test_validation_errors(small_map, tmp_path):
    _res, path = small_map
    with pytest.raises(MapFileError, match="does not exist"):
        load_map(tmp_path / "missing.h5")
    junk = tmp_path / "junk.h5"
    junk.write_text("not hdf5")
    with pytest.raises(MapFileError, match="not an HDF5 file"):
        load_map(junk)
    trunc = tmp_path / "trunc.h5"
    data = path.read_bytes()
    trunc.write_bytes(data[: len(data) // 2])
    with pytest.raises(MapFileError):
        load_map(trunc)
    for attr, value, match in (
        ("schema_version", 99, "schema version 99"),
        ("robot_model_hash", "0" * 64, "another version of the robot .panda."),
        ("schema", "something-else", "not an lmjx map"),
    ):
        bad = tmp_path / f"bad_{attr}.h5"
        shutil.copy(path, bad)
        with h5py.File(bad, "a") as f:
            f.attrs[attr] = value
        with pytest.raises(MapFileError, match=match):
            load_map(bad)
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = 1
    with pytest.raises(MapFileError, match="not an lmjx map"):
        load_map(other)


def _datasets(path):
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
        attrs = {k: f.attrs[k] for k in f.attrs}
    return out, attrs


@pytest.fixture(scope="module")
def built_maps(tmp_path_factory):
    """The same build-map command twice (same seed) and once with another seed."""
    import subprocess
    import sys

    d = tmp_path_factory.mktemp("built")
    paths = []
    for name, seed in (("a.h5", 5), ("b.h5", 5)):
        p = d / name
        r = subprocess.run(
            [sys.executable, "-m", "lmjx.cli", "build-map", "--failure", "case2", "--edges", "400", "--cell", "0.05",
             "--seed", str(seed), "--out", str(p), "--json"],
            capture_output=True, text=True, timeout=900, env={**__import__("os").environ, "JAX_PLATFORMS": "cpu"},
        )  # fmt: skip
        assert r.returncode == 0, r.stderr
        paths.append(p)
    return paths


def test_same_command_same_seed_identical_datasets(built_maps):
    a, b = built_maps
    da, aa = _datasets(a)
    db, ab = _datasets(b)
    assert set(da) == set(db) and "edges/q" in da and "reach/labels" in da
    for k in da:
        x, y = np.asarray(da[k]), np.asarray(db[k])
        same = np.array_equal(x, y, equal_nan=True) if x.dtype.kind == "f" else np.array_equal(x, y)
        assert same, k
    assert {k: str(v) for k, v in aa.items()} == {k: str(v) for k, v in ab.items()}
    # (another seed gives other edges: tests/test_bundle.py)


def test_load_map_with_edges(built_maps):
    m = load_map(built_maps[0])
    assert m.edges is not None and m.edges.n_edges > 0
    assert m.edges.config.seed == 5 and m.edges.sampled == 400
    e = m.edges.edge(0)
    assert e["q"].shape[1] == 7 and len(e["q"]) == m.edges.length[0]


def test_damaged_edge_file_is_refused(built_maps, tmp_path):
    bad = tmp_path / "bad.h5"
    shutil.copy(built_maps[0], bad)
    with h5py.File(bad, "a") as f:
        del f["edges/q"]
    with pytest.raises(MapFileError, match="damaged or incomplete"):
        load_map(bad)
