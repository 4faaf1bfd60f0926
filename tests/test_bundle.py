"""Edge bundles: the rollout kernel against a serial C MuJoCo reference, every rejection
reason, valid edges replayed in C MuJoCo, the spatial index, determinism."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from kernels.rollout import REASONS, Limits
from lmjx.edges.chunk import build_bundle
from lmjx.edges.rollout_ref import ReferenceRollout
from lmjx.edges.sampling import rollout_kernel
from lmjx.errors import ConfigError
from lmjx.mapfile.bundle import BundleConfig
from lmjx.mapfile.read import load_map
from lmjx.model.failure import parse_failure
from lmjx.reach.reachability import attempt_plan

CONFIG = BundleConfig()  # the edges' settings (100 steps of 0.02 s at most)
SETTINGS = CONFIG.rollout_settings()
LONGEST = 60  # the random edges' lengths: up to this many steps


@pytest.fixture(scope="module")
def case2(robot, small_map):
    """The run's shared case-2 map: its reach map and its edges (707 of 3,000)."""
    m = load_map(small_map, robot)
    return m.reach, m.edges


def _random_edges(robot, reach, n, seed, speed=(0.1, 0.8)):
    """Starts taken from the reach map's solutions (each with the point its cell was solved
    for: the TCP, the hand, ...), random twists and lengths.  Where no start is a grasp (no
    TCP), the sites are the edges' own interaction points, and the program the builds run."""
    rng = np.random.default_rng(seed)
    cells = np.argwhere(reach.labels > 0)
    pick = cells[rng.integers(0, len(cells), n)]
    free = list(reach.failure.free())
    q0 = np.array([reach.q[i, j][free] for i, j in pick], np.float32)
    sites = attempt_plan(robot, reach.config)[0]  # the map's sites: the TCP, then the points
    if robot.tcp_site not in {reach.site[i, j] for i, j in pick}:
        sites = sites[1:]
    which = np.array([sites.index(reach.site[i, j]) for i, j in pick], np.int32)
    d = rng.uniform(-1, 1, (n, 6))
    twist = (d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(*speed, (n, 1))).astype(np.float32)
    length = rng.integers(5, LONGEST + 1, n).astype(np.int32)
    return sites, which, q0, twist, length


def _run_kernel(robot, failure, sites, which, q0, twist, length, limits=None):
    """The edges' rollout (their settings; one program per failure and run: the limits are
    its inputs) on `sites`, every edge's states coming back."""
    kernel = rollout_kernel(robot, failure, CONFIG, CONFIG.kernel_chunk(), limits, valid_only=False, sites=sites)
    return kernel.run(which, q0, twist, length)


@pytest.mark.parametrize("spec", ["case1", "case2", "none"])
def test_rollouts_match_c_mujoco_reference(robot, coarse, spec):
    """Same states, same verdict, same first violating state and reason as the reference."""
    failure = parse_failure(spec, robot)
    reach = coarse[spec]
    sites, which, q0, twist, length = _random_edges(robot, reach, 30, seed=7)
    out = _run_kernel(robot, failure, sites, which, q0, twist, length)
    ref = ReferenceRollout(robot, failure, SETTINGS)
    free = list(failure.free())
    for e in range(len(q0)):
        r = ref.run(sites[which[e]], q0[e].astype(np.float64), twist[e].astype(np.float64), int(length[e]))
        assert bool(out["valid"][e]) == r.valid
        assert int(out["fail_step"][e]) == r.fail_step
        assert REASONS[int(out["reason"][e])] == r.reason
        n = len(r.q)
        assert np.abs(out["q"][e, :n] - r.q[:, free]).max() < 1e-4
        assert np.all(np.abs(out["qd"][e, :n] - r.qd[:, free]) <= 1e-3 * np.maximum(1.0, np.abs(r.qd[:, free])))
        assert np.abs(out["p"][e, :n] - r.p).max() < 1e-4
        if r.valid:
            assert out["min_manipulability"][e] == pytest.approx(r.manipulability.min(), rel=1e-3)
            ratio = np.max(np.abs(r.tau[:, free]) / robot.tau_max[free])
            assert out["peak_torque_ratio"][e] == pytest.approx(ratio, rel=1e-3)


def test_every_rejection_reason_is_caught_and_confirmed(robot, coarse):
    """Edges that break each limit and each collision type are rejected at the state where the
    C MuJoCo reference finds the same violation.  The Panda's torque limits are not reached by
    these twists, so the torque check is exercised with limits lowered to 30 % (kernel and
    reference alike)."""
    low_tau = Limits(robot.qd_max, robot.qdd_max, 0.3 * robot.tau_max, robot.friction)
    found = {}
    for spec in ("case1", "case2"):
        failure = parse_failure(spec, robot)
        reach = coarse[spec]
        edges = _random_edges(robot, reach, 400, seed=11, speed=(0.1, 3.0))
        for limits in (None, low_tau):
            out = _run_kernel(robot, failure, *edges, limits)
            for e in range(len(edges[2])):
                name = REASONS[int(out["reason"][e])]
                if name != "ok" and name not in found:
                    found[name] = (failure, edges, e, int(out["fail_step"][e]), limits)
    assert set(found) == set(REASONS[1:]), f"reasons seen: {sorted(found)}"
    for name, (failure, (sites, which, q0, twist, length), e, step, limits) in found.items():
        ref = ReferenceRollout(robot, failure, SETTINGS, limits)
        r = ref.run(sites[which[e]], q0[e].astype(np.float64), twist[e].astype(np.float64), int(length[e]))
        assert (r.reason, r.fail_step) == (name, step)


def test_valid_edges_replayed_in_mujoco(robot, case2):
    """Every stored state of every valid edge: no contact in C MuJoCo, limits hold, locked
    joints exact, and the stored point position is the site's FK."""
    _, b = case2
    assert b.n_edges > 50
    m = robot.mj
    d = mujoco.MjData(m)
    locked = [j - 1 for j in b.failure.locked_joints]
    qf = b.failure.q_fixed().astype(np.float32)
    assert np.all(b.q[:, locked] == qf[locked]) and np.all(b.qd[:, locked] == 0)
    assert np.all(b.q >= robot.lower - 1e-5) and np.all(b.q <= robot.upper + 1e-5)
    assert np.all(np.abs(b.qd) <= robot.qd_max + 1e-6)
    assert np.all(b.peak_torque_ratio <= 1) and np.all(b.peak_velocity_ratio <= 1)
    assert np.all(b.peak_acceleration_ratio <= 1)
    site_of_row = np.repeat(b.site, b.length)
    for row in range(len(b.q)):
        d.qpos[:] = b.q[row]
        mujoco.mj_forward(m, d)
        assert d.ncon == 0
        assert np.linalg.norm(d.site_xpos[site_of_row[row]] - b.p[row]) < 1e-5
    # and the reference agrees that a sample of them is valid
    ref = ReferenceRollout(robot, b.failure, b.config.rollout_settings())
    free = list(b.failure.free())
    names = [robot.site_names[s] for s in b.site]
    for e in range(0, b.n_edges, max(1, b.n_edges // 15)):
        r = ref.run(robot.site_index(names[e]), b.q[b.offset[e]][free].astype(np.float64),
                    b.twist[e].astype(np.float64), int(b.length[e] - 1))  # fmt: skip
        assert r.valid and len(r.q) == b.length[e]


def _capsules_mujoco(robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """C MuJoCo's world endpoints (n, nc, 3) of the table-checked capsule geoms at the
    configurations q (n, nj), and their radii (nc,)."""
    m, d = robot.mj, mujoco.MjData(robot.mj)
    caps = [g for g in range(m.ngeom) if m.geom_bodyid[g] != 0 and (m.geom_contype[g] or m.geom_conaffinity[g])]
    caps = [caps[i] for i in robot.arm.table_caps]
    a = np.zeros((len(q), len(caps), 3))
    b = np.zeros_like(a)
    for i, x in enumerate(q):
        d.qpos[:] = x
        mujoco.mj_kinematics(m, d)
        for k, g in enumerate(caps):
            axis = d.geom_xmat[g].reshape(3, 3)[:, 2] * m.geom_size[g][1]
            a[i, k], b[i, k] = d.geom_xpos[g] - axis, d.geom_xpos[g] + axis
    return a, b, np.array([m.geom_size[g][0] for g in caps])


def _reference_cells(reach, robot, q: np.ndarray, height: float, shrink: float) -> set[int]:
    """Cells whose square some capsule of some state comes within its radius (+ shrink, which
    may be negative) of, with the capsule's surface below `height` there: every axis sampled
    at 200 points (C MuJoCo's geometry)."""
    a, b, r = _capsules_mujoco(robot, q)
    t = np.linspace(0, 1, 200)[:, None, None, None]
    pts = a[None] * (1 - t) + b[None] * t  # (200, n, nc, 3)
    low = pts[..., 2] - robot.arm.table_z - r <= height
    rad = np.broadcast_to(r + shrink, low.shape)[low]
    xy = pts[low][:, :2]
    cell, nx, ny = reach.config.cell, len(reach.xs), len(reach.ys)
    found = set()
    cx, cy = np.meshgrid(reach.xs, reach.ys)
    for (x, y), rr in zip(xy, rad, strict=True):
        gx = np.maximum(np.abs(x - cx) - cell / 2, 0.0)
        gy = np.maximum(np.abs(y - cy) - cell / 2, 0.0)
        iy, ix = np.nonzero(gx * gx + gy * gy <= rr * rr)
        found.update((iy * nx + ix).tolist())
    assert all(0 <= c < nx * ny for c in found)
    return found


def test_spatial_index_is_the_whole_arm_against_c_mujoco(robot, case2):
    """The spatial index lists an edge at a cell when a capsule of the arm, swept over the
    edge's states, comes within its radius of the cell with its surface low enough there: for
    a sample of edges, every cell C MuJoCo's capsules reach by a clear margin (radius less a
    quarter cell and 1 mm: the index samples the axes every half cell; here densely) is
    listed, and every listed cell is reached (radius plus 1 mm: float32)."""
    reach, b = case2
    nx, ny = len(reach.xs), len(reach.ys)
    assert len(b.index_offset) == nx * ny + 1 and b.index_offset[-1] == len(b.index_edges)
    listed: dict[int, set[int]] = {}
    for c in range(nx * ny):
        for e in b.index_edges[b.index_offset[c] : b.index_offset[c + 1]]:
            listed.setdefault(int(e), set()).add(c)
    height = b.config.index_height
    edges = list(range(0, b.n_edges, max(1, b.n_edges // 12)))
    checked = 0
    for e in edges:
        q = b.edge(e)["q"].astype(np.float64)
        inner = _reference_cells(reach, robot, q, height - 0.001, -(reach.config.cell / 4 + 0.001))
        outer = _reference_cells(reach, robot, q, height + 0.001, 0.001)
        got = listed.get(e, set())
        assert inner <= got <= outer, (e, sorted(inner - got), sorted(got - outer))
        checked += len(got)
    assert checked > 20
    # the whole arm reaches more than the interaction point alone did
    assert len(b.index_edges) > 0


def test_same_seed_same_bundle(robot, case2):
    reach, _ = case2
    config = BundleConfig(edges=400, seed=3)
    b, again = (build_bundle(reach, config, robot=robot) for _ in range(2))
    for f in dataclasses.fields(b):
        if f.name in ("seconds", "compile_seconds", "rollout_seconds", "config", "failure"):
            continue
        x, y = getattr(b, f.name), getattr(again, f.name)
        assert np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y, f.name
    other = build_bundle(reach, dataclasses.replace(config, seed=4), robot=robot)
    assert not np.array_equal(other.twist[:10], b.twist[:10])


def test_bad_bundle_config(robot, case2):
    reach, _ = case2
    for kw in (dict(edges=0), dict(dt=0.0), dict(duration_range=(2.0, 1.0)), dict(interaction_points=("nose",))):
        with pytest.raises(ConfigError):
            build_bundle(reach, BundleConfig(**kw), robot=robot)
