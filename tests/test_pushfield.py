"""The push counts (`lmjx.mapfile.pushmap`): the two-stage computation gives the pairs of the
reference (tests/reference_pushfield.py: every state of every edge through the kernels)
exactly, on the planner's map and on edges built to hit its corner cases; its device program
against the capsule kernel and C MuJoCo; a built map stores the counts of the robot's
built-in scenarios (both writers), the planner reads them, and a map of schema version 2
has them computed and cached."""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import sys

import h5py
import mujoco
import numpy as np
import pytest
from conftest import benchmark_module, random_configs
from reference_pushfield import reference_push_pairs

from lmjx.edges.index import capsule_ends_kernel
from lmjx.mapfile import pushmap, pushsamples
from lmjx.mapfile.digest import content_digest
from lmjx.mapfile.read import load_map
from lmjx.mapfile.write import write_map
from lmjx.planner.clearance import park_pose
from lmjx.planner.scoring import _score_field
from lmjx.planner.transit import TransitPlanner
from lmjx.sim.scenarios import SCENARIOS, TASK_SETS, scenario
from lmjx.sim.sceneboxes import MIN_EDGE_STATES
from lmjx.types import PlannerConfig

LOW_TOL = 2e-5  # [m] float32 kinematics against C MuJoCo's float64


@pytest.fixture(scope="module")
def plan(plan_map):
    """The planner tests' map, read whole."""
    return load_map(plan_map, lazy=False)


def _bundle_of(b, edges: list[np.ndarray]):
    """A bundle of the given edges' states (what the push counts read of a bundle)."""
    length = np.array([len(e) for e in edges], np.int32)
    offset = np.concatenate([[0], np.cumsum(length)[:-1]]).astype(np.int64)
    q = np.concatenate(edges).astype(np.float32)
    return dataclasses.replace(b, offset=offset, length=length, q=q, q_start=q[offset], push={})


def _same_pairs(robot, m, bundle, sc) -> tuple[np.ndarray, np.ndarray]:
    """The two-stage pairs, checked equal to the reference's; returned."""
    field = pushmap.scenario_field(robot, sc)
    cells, edges = pushmap.push_pairs(robot, m.failure, bundle, m.reach, sc, field)
    ref_cells, ref_edges = reference_push_pairs(robot, m.failure, bundle, m.reach, sc, field)
    assert np.array_equal(cells, ref_cells) and np.array_equal(edges, ref_edges), (len(cells), len(ref_cells))
    return cells, edges


def test_low_samples_match_the_capsule_kernel_and_c_mujoco(robot):
    """`kernels.push.low_samples` (the program the map's samples come from): the pairs, in
    order, and the lower ends of the capsule-ends kernel bitwise (the low end picked, its
    next state's x, y), counted beyond the budget, limited to the rows asked for; the ends
    against C MuJoCo's capsule geoms."""
    rows, nt = pushsamples._rows(), len(robot.arm.table_caps)
    budget = rows * nt // pushsamples.BUDGET_SHARE
    program = pushsamples._program(robot, rows, budget)  # the program push_samples runs
    q = random_configs(robot, rows + 1, 3).astype(np.float32)
    has_next = np.random.default_rng(4).random(rows) < 0.9
    ends = capsule_ends_kernel(robot).run(q)
    caps = np.asarray(robot.arm.table_caps)
    a, b = ends["a"][:, caps], ends["b"][:, caps]
    low = np.where((a[..., 2] <= b[..., 2])[..., None], a, b)
    # heights under which 5 % and 30 % of the pairs lie: within the budget, and beyond it
    below, above = np.quantile(low[:-1, :, 2], [0.05, 0.3])
    for z_max, span, over in ((below, (0, rows), False), (above, (0, rows), True), (above, (100, 900), False)):
        limit = np.full(nt, z_max, np.float32)
        count, index, got, next_xy = (np.asarray(x) for x in program(q, has_next, limit, np.array(span, np.int32)))
        live = has_next & (np.arange(rows) >= span[0]) & (np.arange(rows) < span[1])
        want = np.nonzero(((low[:-1, :, 2] <= limit) & live[:, None]).ravel())[0]
        assert int(count) == len(want) > 100 and (len(want) > budget) == over
        n = min(len(want), budget)
        assert np.array_equal(index[:n], want[:n])
        s, c = want[:n] // nt, want[:n] % nt
        assert np.array_equal(got[:n], low[s, c]) and np.array_equal(next_xy[:n], low[s + 1, c, :2])
    mj, d = robot.mj, mujoco.MjData(robot.mj)
    geoms = [g for g in range(mj.ngeom) if mj.geom_bodyid[g] != 0]
    for i in range(0, rows, 97):
        d.qpos[:] = q[i]
        mujoco.mj_kinematics(mj, d)
        for j, cap in enumerate(caps):
            g = geoms[cap]
            axis = d.geom_xmat[g].reshape(3, 3)[:, 2] * mj.geom_size[g, 1]
            ends_mj = sorted((d.geom_xpos[g] - axis, d.geom_xpos[g] + axis), key=lambda p: p[2])
            assert abs(low[i, j, 2] - ends_mj[0][2]) <= LOW_TOL
            if ends_mj[1][2] - ends_mj[0][2] > 2 * LOW_TOL:  # (a level capsule: either end)
                np.testing.assert_allclose(low[i, j], ends_mj[0], atol=LOW_TOL)


def test_pairs_equal_the_reference_and_the_map_stores_their_counts(robot, plan, plan_map, tmp_path, monkeypatch):
    """Scenarios 1-3 of both task sets on the planner's map: the same (cell, edge) pairs as
    the reference; the counts the map stores (built by `lmjx build-map`, streamed) are
    theirs, under the planner's key; the in-memory writer stores the same; the map opened
    lazily (its states read in blocks) gives the same pairs."""
    b = plan.edges
    assert len(b.push) == len(TASK_SETS) * len(SCENARIOS)
    sums = {}
    for tasks in TASK_SETS:
        for number in sorted(SCENARIOS):
            sc = scenario(number, robot.profile.task_scale, tasks)
            cells, _ = _same_pairs(robot, plan, b, sc)
            key = pushmap.counts_key(robot, b, plan.reach, sc, pushmap.scenario_field(robot, sc))
            assert np.array_equal(b.push[key], pushmap.push_counts(cells, plan.reach))
            sums[tasks, number] = len(cells)
    assert min(sums.values()) > 100
    monkeypatch.setattr(pushmap, "READ_ROWS", 1000)
    with load_map(plan_map, lazy=True) as lazy:
        sc = scenario(2, robot.profile.task_scale, "hard")
        field = pushmap.scenario_field(robot, sc)
        got = pushmap.push_pairs(robot, lazy.failure, lazy.edges, lazy.reach, sc, field)
        want = pushmap.push_pairs(robot, plan.failure, b, plan.reach, sc, field)
        assert lazy.lazy and all(np.array_equal(x, y) for x, y in zip(got, want, strict=True))
    whole = tmp_path / "whole.h5"
    write_map(whole, plan.reach, b, robot)
    again = load_map(whole).edges.push
    assert again.keys() == b.push.keys() and all(np.array_equal(again[k], b.push[k]) for k in again)


def test_an_edge_cut_short_by_a_wall_within_its_first_states_pushes_nothing(robot, plan):
    """The cut-trap: an edge that pushes toward the goal at its first states (the last such
    sample at state kmax) and comes within the wall's margin at state 4, further than
    kmax + 1 but short of MIN_EDGE_STATES, is never offered (its executed part too short):
    it pushes nothing, as in the reference, while the same edge away from the wall pushes."""
    sc = scenario(2, robot.profile.task_scale, "hard")
    field = pushmap.scenario_field(robot, sc)
    b = plan.edges
    tp = TransitPlanner(robot, plan.failure, batched=True)
    tp.set_scene(sc, pushmap.far_objects(sc), acting=False)
    fixed = ~tp.scene.movable

    def near_wall(q: np.ndarray) -> np.ndarray:
        return tp.scene_slacks(np.asarray(q, np.float64))[:, fixed].min(axis=1) < 0

    high = park_pose(robot, plan.failure).astype(np.float32)  # raised: no capsule low over the table
    some = np.arange(0, len(b.q), 7)
    near = near_wall(b.q[some])
    assert near.any()
    wall = b.q[some[np.argmax(near)]]
    s = pushmap.bundle_samples(robot, b, plan.reach, pushmap.HEIGHT, False)
    ok = pushmap._toward(s, field, pushmap.MAX_ANGLE) & (s.k <= 1)
    picked = None
    for e in np.unique(s.sample_edge()[ok]):
        first = b.edge(int(e), ("q",))["q"][:3]
        if len(first) == 3 and not near_wall(np.vstack([first, high[None]])).any():
            picked = first
            break
    assert picked is not None and near_wall(wall[None])[0] and not near_wall(high[None])[0]
    trap = np.vstack([picked, high, wall, wall])  # within the margin first at state 4
    away = np.vstack([picked, high, high, high])
    bundle = _bundle_of(b, [trap, away, b.edge(0, ("q",))["q"]])
    _, edges = _same_pairs(robot, plan, bundle, sc)
    assert 0 not in edges and 1 in edges
    # the trap holds: the trap edge's last sample toward the goal is short of the wall by two states or more
    ts = pushmap.bundle_samples(robot, bundle, plan.reach, pushmap.HEIGHT, False)
    kmax = ts.k[(ts.sample_edge() == 0) & pushmap._toward(ts, field, pushmap.MAX_ANGLE)].max()
    assert kmax + 2 <= 4 < MIN_EDGE_STATES


def test_a_run_with_more_low_pairs_than_its_budget_is_computed_in_parts(robot, plan, monkeypatch):
    """Edges whose every state holds many capsules low over the table: the device program
    passes more pairs than a call returns; the run is split and computed again, and the
    pairs are the reference's."""
    b = plan.edges
    s = pushmap.bundle_samples(robot, b, plan.reach, pushmap.HEIGHT, False)
    row = b.offset[s.sample_edge()] + s.k
    rows, per_state = np.unique(row, return_counts=True)
    busy = rows[(per_state >= 6) & np.isin(rows + 1, rows[per_state >= 6])][0]  # two busy states in a row
    pair = np.asarray(b.q[busy : busy + 2], np.float32)
    edges = [np.tile(pair, (25, 1)) for _ in range(2 * pushsamples._rows() // 50 + 1)]
    splits = []
    real = pushsamples._split
    monkeypatch.setattr(pushsamples, "_split", lambda *a: splits.append(a[4:6]) or real(*a))
    bundle = _bundle_of(b, edges)
    _same_pairs(robot, plan, bundle, scenario(1, robot.profile.task_scale, "paper"))
    assert len(splits) >= 3 and splits[0][0] == 0  # a run, then its halves (at least)
    samples = pushmap.bundle_samples(robot, bundle, plan.reach, pushmap.HEIGHT, False)
    assert samples.runs == -(-len(edges) // (pushsamples._rows() // 50)) and samples.device_calls == len(splits)


def test_the_planner_reads_stored_counts_and_computes_those_a_map_lacks(robot, plan_map, tmp_path, monkeypatch, capsys):
    """`_score_field` with a push weight: the map's stored counts, nothing computed; another
    platform's (its key) or a map of schema version 2 (no /edges/push, read as before):
    computed and kept in the cache folder, the same field; the map's content digest leaves
    the counts out; benchmarks/warm_push_counts.py says where each came from."""
    monkeypatch.setenv("LMJX_CACHE_DIR", str(tmp_path / "cache"))
    cfg = PlannerConfig(push_weight=1.0)
    sc = scenario(2, robot.profile.task_scale, "hard")
    real = pushmap.scenario_counts
    computed = []

    def spy(*args, **kwargs):
        computed.append(args[4])
        return real(*args, **kwargs)

    monkeypatch.setattr(pushmap, "scenario_counts", spy)
    m = load_map(plan_map)
    stored = _score_field(robot, m.failure, m.reach, m.edges, sc, cfg)
    assert computed == [] and not (tmp_path / "cache" / "pushes").exists()
    old = tmp_path / "v2.h5"
    shutil.copy(plan_map, old)
    with h5py.File(old, "a") as f:
        del f["edges/push"]
        f.attrs["schema_version"] = 2
    assert content_digest(old) == content_digest(plan_map)  # (the push counts are not content)
    m2 = load_map(old)
    assert m2.edges.push == {}
    again = _score_field(robot, m2.failure, m2.reach, m2.edges, sc, cfg)
    assert computed == [sc] and len(list((tmp_path / "cache" / "pushes").glob("*.npy"))) == 1
    pts = np.random.default_rng(5).uniform([0.2, 0.0], [0.7, 0.5], (300, 2))
    assert np.array_equal(again(pts), stored(pts))
    warm = benchmark_module("warm_push_counts").main
    capsys.readouterr()
    assert warm(["--map", str(plan_map), "--tasks", "hard", "--scenarios", "2"]) == 0
    assert warm(["--map", str(old), "--tasks", "hard", "--scenarios", "2,3"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "stored in the map" in lines[0] and "read from the cache folder" in lines[1] and "computed" in lines[2]
    assert warm(["--map", str(plan_map), "--tasks", "hard", "--scenarios", "2", "--compute"]) == 0
    assert "computed, equal to the map's" in capsys.readouterr().out
    assert warm(["--map", str(old), "--scenarios", "x"]) == 2
    monkeypatch.setattr(pushmap, "backend", lambda: "gpu")  # counts stored on another platform: not used
    other = load_map(plan_map)
    _score_field(robot, other.failure, other.reach, other.edges, sc, cfg)
    # (between: warm_push_counts' scenario 3 on the old map, and its --compute)
    assert computed == [sc, scenario(3, robot.profile.task_scale, "hard"), sc, sc]


def test_push_samples_run_on_the_device_asked_for(plan_map):
    """`push_samples(device=...)` (a build's packers spread them over the GPUs): its runs'
    program runs on that device from the worker threads (JAX's default device is a setting
    of the thread that enters it), with the samples it gives on the default device.  In a
    process of two host devices."""
    code = r"""
import sys
import jax
import numpy as np
from lmjx.mapfile.read import load_map
from lmjx.mapfile import pushsamples
from lmjx.mapfile.pushmap import HEIGHT

m = load_map(sys.argv[1], lazy=False)
seen = []
real = pushsamples._split


def spy(program, *args):
    def placed(*a):
        out = program(*a)
        seen.append(tuple(sorted(d.id for d in out[0].devices())))
        return out

    return real(placed, *args)


pushsamples._split = spy
one = pushsamples.push_samples(m.robot, m.edges, m.reach, HEIGHT, workers=2)
first = set(seen)
seen.clear()
two = pushsamples.push_samples(m.robot, m.edges, m.reach, HEIGHT, workers=2, device=jax.devices()[1])
assert first == {(0,)} and set(seen) == {(1,)}, (first, set(seen))
names = ("k", "p", "p_next", "group_start", "group_edge", "group_cell")
assert len(one) > 0 and all(np.array_equal(getattr(one, k), getattr(two, k)) for k in names)
print("ok")
"""
    env = dict(os.environ, JAX_PLATFORMS="cpu", XLA_FLAGS="--xla_force_host_platform_device_count=2")
    r = subprocess.run([sys.executable, "-c", code, str(plan_map)], env=env, capture_output=True, text=True,
                       timeout=600)  # fmt: skip
    assert r.returncode == 0 and r.stdout.strip().endswith("ok"), r.stderr[-2000:]
