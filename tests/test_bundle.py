"""Edge bundles: the rollout kernel against a serial C MuJoCo reference, every rejection
reason, valid edges replayed in C MuJoCo, the spatial index, determinism."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from lmjx.bundle import BundleConfig, build_bundle, index_pairs, rollout_kernel
from lmjx.errors import ConfigError
from lmjx.failure import parse_failure
from lmjx.kernels.rollout import REASONS, Limits
from lmjx.mapfile import load_map
from lmjx.reach import attempt_plan
from lmjx.rollout_ref import ReferenceRollout

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


def test_spatial_index(robot, case2):
    reach, b = case2
    nx, ny = len(reach.xs), len(reach.ys)
    assert len(b.index_offset) == nx * ny + 1 and b.index_offset[-1] == len(b.index_edges)
    cell = reach.config.cell
    radius = robot.arm.site_radius
    listed = 0
    for iy in range(ny):
        for ix in range(nx):
            for e in b.edges_over(iy, ix, nx):
                s = b.edge(int(e))["p"]
                r = radius[b.site[e]]
                # some point of the edge's path (states and the segments between them) is over the cell, low
                a, c = s[:-1], s[1:]
                t = np.linspace(0, 1, 9)[:, None, None]
                path = (a[None] * (1 - t) + c[None] * t).reshape(-1, 3) if len(s) > 1 else s
                over = (np.abs(path[:, 0] - reach.xs[ix]) <= cell / 2 + 1e-6) & (
                    np.abs(path[:, 1] - reach.ys[iy]) <= cell / 2 + 1e-6
                )
                assert np.any(over & (path[:, 2] - r <= b.config.index_height + 1e-6))
                listed += 1
    assert listed == len(b.index_edges) > 0


def test_index_pairs_equal_every_sampled_point(case2):
    """The spatial index lists exactly the (cell, edge) pairs that sampling every step segment
    at `substeps` points and every edge's last state gives, point by point (no segment
    skipped): paths that skim the index height from above and below, and leave the table."""
    reach, b = case2
    rng = np.random.default_rng(5)
    height, substeps = b.config.index_height, b.config.index_substeps
    length = rng.integers(1, 40, 300)
    radius = rng.uniform(0.0, 0.05, len(length)).astype(np.float32)
    x0, x1 = reach.xs[0] - 0.2, reach.xs[-1] + 0.2
    y0, y1 = reach.ys[0] - 0.2, reach.ys[-1] + 0.2
    paths = []
    for n, r in zip(length, radius, strict=True):
        a, c = rng.uniform((x0, y0), (x1, y1), (2, 2))
        xy = a + (c - a) * np.linspace(0, 1, n)[:, None]
        z = height + r + rng.choice([1e-7, -1e-7, 1e-4, 0.02]) * np.cos(rng.uniform(0, 6, n) + np.arange(n))
        paths.append(np.column_stack([xy, z]).astype(np.float32))
    p = np.concatenate(paths)
    cell_of, edge_of = index_pairs(reach, p, length, radius, height, substeps)
    want = set()
    nx = len(reach.xs)
    for e, s in enumerate(paths):
        t = (np.arange(substeps) / substeps).astype(np.float32)
        pts = [s[i] * (1 - tt) + s[i + 1] * tt if k else s[i] for i in range(len(s) - 1) for k, tt in enumerate(t)]
        for pt in [*pts, s[-1]]:
            ix = int(np.floor((pt[0] - (reach.xs[0] - reach.config.cell / 2)) / reach.config.cell))
            iy = int(np.floor((pt[1] - (reach.ys[0] - reach.config.cell / 2)) / reach.config.cell))
            if pt[2] - radius[e] <= height and 0 <= ix < nx and 0 <= iy < len(reach.ys):
                want.add((iy * nx + ix, e))
    got = list(zip(cell_of.tolist(), edge_of.tolist(), strict=True))
    assert got == sorted(want) and len(want) > 100


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
