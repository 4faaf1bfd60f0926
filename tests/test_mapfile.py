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


def test_plain_h5py_by_the_documented_schema(small_map, robot):
    """Read the file the way maps/README.md tells a non-Python user to (no lmjx calls)."""
    _res, path = small_map
    with h5py.File(path, "r") as f:
        assert f.attrs["schema"] == "lmjx-map" and int(f.attrs["schema_version"]) == 1
        labels = f["reach/labels_smooth"][...]
        cell = float(f["reach"].attrs["cell"])
        pm_area = np.sum(labels == 2) * cell**2
        npm_area = np.sum(labels >= 1) * cell**2
        assert pm_area == pytest.approx(float(f["reach"].attrs["area_pm_m2"]))
        assert npm_area == pytest.approx(float(f["reach"].attrs["area_npm_pm_m2"]))
        x, y = f["reach/x"][...], f["reach/y"][...]
        iy, ix = np.argwhere(labels == 2)[0]
        q = f["reach/q"][iy, ix]
        site = f["robot/site_names"][f["reach/site"][iy, ix]].decode()
        assert site == "tcp"
        mjcf = f["robot/mjcf"][()].decode()
        assert "lmjx_panda" in mjcf
        assert list(f.attrs["locked_joints"]) == [3, 5, 7]
    # The stored solution places the TCP on the stored target (checked with the model text).
    import mujoco

    m = mujoco.MjModel.from_xml_string(mjcf)
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    assert np.linalg.norm(d.site_xpos[m.site("tcp").id][:2] - [x[ix], y[iy]]) <= cell / 2 * np.sqrt(2) + 0.002


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
        ("robot_model_hash", "0" * 64, "another robot model"),
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
