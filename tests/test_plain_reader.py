"""Reading a built map the way maps/README.md tells a user of plain h5py, MATLAB or C++ to:
this module imports no lmjx; the map is the run's shared one, built by the `lmjx build-map`
command (tests/conftest.py)."""

from __future__ import annotations

import h5py
import mujoco
import numpy as np
import pytest


@pytest.fixture(scope="module")
def map_file(small_map):
    return small_map


def test_reach_map_by_the_schema(map_file):
    with h5py.File(map_file, "r") as f:
        assert f.attrs["schema"] == "lmjx-map" and int(f.attrs["schema_version"]) == 3
        assert f.attrs["contents"] == "reach+edges" and f.attrs["failure"] == "case2"
        assert list(f.attrs["locked_joints"]) == [6, 7]
        g = f["reach"]
        cell = float(g.attrs["cell"])
        lab = g["labels_smooth"][...]
        assert np.sum(lab == 2) * cell**2 == pytest.approx(float(g.attrs["area_pm_m2"]))
        assert np.sum(lab >= 1) * cell**2 == pytest.approx(float(g.attrs["area_npm_pm_m2"]))
        iy, ix = np.argwhere(g["labels"][...] >= 1)[0]
        q = g["q"][iy, ix]
        site = f["robot/site_names"][g["site"][iy, ix]].decode()
        x, y, zlo, zhi = g["target"][iy, ix]
        mjcf = f["robot/mjcf"][()].decode()
    m = mujoco.MjModel.from_xml_string(mjcf)
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_forward(m, d)
    p = d.site_xpos[m.site(site).id]
    assert np.hypot(p[0] - x, p[1] - y) <= 0.002 + 1e-6 and zlo - 0.002 <= p[2] <= zhi + 0.002
    assert d.ncon == 0


def test_reconstruct_an_edge(map_file):
    """Find the edges over a cell with the spatial index, slice one out of the flat arrays,
    and check it against the stored model with MuJoCo's own FK."""
    with h5py.File(map_file, "r") as f:
        e = f["edges"]
        off, ln = e["offset"][...], e["length"][...]
        nx = int(e["index"].attrs["nx"])
        io, ie = e["index/offset"][...], e["index/edges"][...]
        c = int(np.argmax(np.diff(io)))  # the busiest cell
        edge = int(ie[io[c]])
        iy, ix = divmod(c, nx)
        rows = slice(int(off[edge]), int(off[edge] + ln[edge]))
        q, qd, p = e["q"][rows], e["qd"][rows], e["p"][rows]
        dt = float(e.attrs["dt"])
        site = f["robot/site_names"][e["site"][edge]].decode()
        twist = e["twist"][edge]
        mjcf = f["robot/mjcf"][()].decode()
        x, y = f["reach/x"][ix], f["reach/y"][iy]
        cell = float(f["reach"].attrs["cell"])
        e_attrs_height = e["index"].attrs["height"]
        assert int(e.attrs["edges_valid"]) == len(off)
    assert len(q) == ln[edge] >= 2 and twist.shape == (6,)
    np.testing.assert_allclose(q[1:], q[:-1] + qd[:-1] * dt, atol=1e-5)  # the integration rule
    m = mujoco.MjModel.from_xml_string(mjcf)
    d = mujoco.MjData(m)
    for qi, pi in zip(q, p, strict=True):
        d.qpos[:] = qi
        mujoco.mj_forward(m, d)
        np.testing.assert_allclose(d.site_xpos[m.site(site).id], pi, atol=1e-5)
        assert d.ncon == 0
    # the arm does pass by that cell, low: some capsule's axis comes within its radius of the
    # cell's square at a point less than the index height (plus the radius) above the table
    height = float(e_attrs_height)
    near = np.inf
    caps = [g for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE and m.geom_bodyid[g] != 0
            and m.geom_contype[g]]  # fmt: skip
    for qi in q:
        d.qpos[:] = qi
        mujoco.mj_kinematics(m, d)
        for g in caps:
            axis = d.geom_xmat[g].reshape(3, 3)[:, 2] * m.geom_size[g][1]
            pts = d.geom_xpos[g] + np.linspace(-1, 1, 101)[:, None] * axis
            low = pts[:, 2] - m.geom_size[g][0] <= height + 1e-3
            gx = np.maximum(np.abs(pts[low, 0] - x) - cell / 2, 0.0)
            gy = np.maximum(np.abs(pts[low, 1] - y) - cell / 2, 0.0)
            if low.any():
                near = min(near, float(np.min(np.hypot(gx, gy) - m.geom_size[g][0])))
    assert near <= 1e-3


def test_push_counts_by_the_schema(map_file):
    """/edges/push: the counts of scenarios 1-3 of both task sets, one (ny, nx) grid each,
    computed on the build's platform; a cell's count is at most the edges the spatial index
    lists there (an edge pushing over a cell passes low over it)."""
    with h5py.File(map_file, "r") as f:
        g = f["edges/push"]
        ny, nx = f["reach/labels"].shape
        pairs = sorted(zip(g["scenario"][...].tolist(), [t.decode() for t in g["tasks"][...]], strict=True))
        counts = g["counts"][...]
        keys = [k.decode() for k in g["key"][...]]
        platform = g.attrs["platform"]
        per_cell = np.diff(f["edges/index/offset"][...]).reshape(ny, nx)
    assert pairs == sorted((s, t) for s in (1, 2, 3) for t in ("paper", "hard"))
    assert counts.shape == (6, ny, nx) and counts.dtype == np.int32 and len(set(keys)) == 6
    assert platform == "cpu" and counts.min() >= 0 and counts.sum() > 0
    assert np.all(counts <= per_cell[None])
