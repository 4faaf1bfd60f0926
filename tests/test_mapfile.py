"""Map files: round trip, validation errors.  (Plain-h5py reading by the documented schema:
tests/test_plain_reader.py; the same command and seed give the same file:
tests/test_edgestream.py.)"""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

from lmjx.errors import MapFileError
from lmjx.mapfile.read import load_map
from lmjx.mapfile.write import write_reach_map


@pytest.fixture(scope="module")
def case1_file(robot, coarse, tmp_path_factory):
    res = coarse["case1"]
    path = tmp_path_factory.mktemp("maps") / "case1.h5"
    write_reach_map(path, res, robot)
    return res, path


def test_round_trip(case1_file):
    res, path = case1_file
    m = load_map(path)
    assert m.failure.spec == res.failure.spec and m.failure.locked == res.failure.locked
    r = m.reach
    assert r.config == res.config
    for k in ("xs", "ys", "labels", "labels_smooth", "attempt", "site"):
        assert np.array_equal(getattr(r, k), getattr(res, k)), k
    for k in ("q", "target", "pos_err"):
        assert np.array_equal(getattr(r, k), getattr(res, k), equal_nan=True), k
    assert r.areas() == res.areas()


def test_validation_errors(case1_file, tmp_path):
    _res, path = case1_file
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
        ("schema_version", 1, "whole arm; rebuild it with lmjx build-map --failure"),
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


def test_load_map_with_edges(small_map):
    m = load_map(small_map)
    assert m.edges is not None and m.edges.n_edges > 0
    assert m.edges.config.seed == 1 and m.edges.sampled == 3000
    e = m.edges.edge(0)
    assert e["q"].shape[1] == 7 and len(e["q"]) == m.edges.length[0]
    # the reach map alone (what `build_map` reads back after a build): the same reach map,
    # and none of the edges' group
    r = load_map(small_map, with_edges=False)
    assert r.edges is None and r.edges_attrs == {}
    assert r.reach.summary() == m.reach.summary()
    np.testing.assert_array_equal(r.reach.labels, m.reach.labels)


def test_damaged_edge_file_is_refused(small_map, tmp_path):
    bad = tmp_path / "bad.h5"
    shutil.copy(small_map, bad)
    with h5py.File(bad, "a") as f:
        del f["edges/q"]
    with pytest.raises(MapFileError, match="damaged or incomplete"):
        load_map(bad)


def test_files_being_written_hold_no_lock(tmp_path):
    """lmjx opens the files it writes without HDF5's locks (`lmjx.mapfile.h5`): a process that
    inherited or shares the descriptor of a file being written (a compiler's child) leaves
    no lock behind.  While one is open to write here, another process opens it to read
    with HDF5's locks; with h5py's default there, it could not (errno 11)."""
    import subprocess
    import sys

    from lmjx.mapfile.h5 import h5open

    path = tmp_path / "w.h5"
    probe = [sys.executable, "-c", "import h5py, sys; h5py.File(sys.argv[1], 'r', locking=True).close()", str(path)]
    with h5open(path, "w") as f:
        f["x"] = np.arange(3)
        f.flush()
        assert subprocess.run(probe, capture_output=True).returncode == 0
    with h5py.File(path, "w", locking=True) as f:  # (what the probe meets without lmjx's open)
        f["x"] = np.arange(3)
        f.flush()
        assert subprocess.run(probe, capture_output=True).returncode != 0
    with h5open(path) as f, h5py.File(path, "r") as g:  # to read: as h5py opens it (the same locking)
        assert np.array_equal(f["x"][...], g["x"][...])
