"""Edges turned about the base joint (`lmjx.planner.turned`): a turned edge is the edge the
rollout kernel gives from the turned start with the turned twist; the tunnel's first decision
offers more actions with them; the paper's settings leave them out; the planner records the
turn of the edge it executes."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from lmjx.edges.sampling import rollout_kernel
from lmjx.mapfile.bundle import BundleConfig
from lmjx.mapfile.read import load_map
from lmjx.planner.edge_planner import edges_over_target
from lmjx.planner.trial import setup_trial
from lmjx.planner.turned import TurnedEdges, turn_axis, turn_xy
from lmjx.reach.reachability import attempt_plan, reach_config
from lmjx.sim.scenarios import resolve_task
from lmjx.types import PlannerConfig

CONFIG = BundleConfig()
TURNS_DEG = (-50, -17, 8, 33, 71)


def test_a_turned_edge_is_the_rollout_from_the_turned_start(robot, small_map):
    """Edges of the shared case-2 map rolled out again by the build's kernel from q_start with
    J1 turned by delta and the twist turned with it: the same states as the stored edge turned
    (`TurnedEdges.edge`: q with J1 + delta, qd unchanged, the point turned about the axis), the
    same peak torque, velocity and acceleration ratios, within float32 rounding."""
    m = load_map(small_map, robot)
    b, failure = m.edges, m.failure
    axis = turn_axis(robot, failure)
    assert axis is not None and robot.joint_names[axis.joint] == robot.joint_names[0]
    assert axis.sign == 1.0 and np.allclose(axis.anchor, 0.0)
    free = list(failure.free(robot.nq))
    sites = attempt_plan(robot, reach_config(robot))[0][1:]  # the build's program (no TCP)
    rng = np.random.default_rng(3)
    ids, deltas = [], []
    for e in rng.permutation(b.n_edges):  # edges whose J1 stays within its limits turned
        d = np.radians(TURNS_DEG[len(ids)])
        q1 = b.edge(int(e), ("q",))["q"][:, axis.joint] + d
        if q1.min() >= robot.lower[axis.joint] and q1.max() <= robot.upper[axis.joint]:
            ids.append(int(e))
            deltas.append(d)
        if len(ids) == len(TURNS_DEG):
            break
    view = TurnedEdges(b, np.array(ids), np.array(deltas), axis)
    which = np.array([sites.index(int(b.site[e])) for e in ids], np.int32)
    q0 = view.q_start[:, free].astype(np.float32)
    twist = b.twist[ids].astype(np.float64)
    twist[:, 0:2] = turn_xy(twist[:, 0:2], np.array(deltas), np.zeros(2))  # linear and angular: about z
    twist[:, 3:5] = turn_xy(twist[:, 3:5], np.array(deltas), np.zeros(2))
    length = (b.length[ids] - 1).astype(np.int32)
    kernel = rollout_kernel(robot, failure, CONFIG, CONFIG.kernel_chunk(), valid_only=False, sites=sites)
    out = kernel.run(which, q0, twist.astype(np.float32), length)
    for i, e in enumerate(ids):
        assert bool(out["valid"][i])
        mine = view.edge(i)
        n = len(mine["q"])
        assert np.abs(out["q"][i, :n] - mine["q"][:, free]).max() < 2e-5
        assert np.abs(out["qd"][i, :n] - mine["qd"][:, free]).max() < 2e-4
        assert np.abs(out["p"][i, :n] - mine["p"]).max() < 2e-5
        for k in ("peak_torque_ratio", "peak_velocity_ratio", "peak_acceleration_ratio"):
            assert out[k][i] == pytest.approx(getattr(b, k)[e], rel=1e-3, abs=1e-5), k
        unturned = b.edge(e)
        assert np.array_equal(mine["qd"], unturned["qd"])
        assert np.allclose(mine["q"][:, 1:], unturned["q"][:, 1:]) and np.allclose(mine["p"][:, 2], unturned["p"][:, 2])


def _first_decision(robot, m, cfg, seed):
    """The tunnel's (hard set's) first decision's offer: the planner's candidates in its order
    (the map's, then turned copies with turn_edges), up to 24 actions."""
    setup = setup_trial(robot, m, resolve_task(2, robot, "hard"), cfg, seed)
    pl = setup.planner
    obs = setup.world.reset(setup.layout, pl.transits.park)
    pl.transits.set_scene(pl.sc, obs.objects)
    target, half = obs.objects[0, :2], float(pl.sc.target.half[0])
    rng = np.random.default_rng(seed)
    order = rng.permutation(edges_over_target(pl.bundle, pl.reach, target, half, cfg.target_margin))
    bundle, order = pl._with_turned(order, target, half, rng) if cfg.turn_edges else (pl.bundle, order)
    return pl, obs, bundle, pl.transits.actions(bundle, order, obs.robot_q, 24)


def test_turned_edges_offer_more_actions_in_the_tunnel(robot, plan_map):
    m = load_map(plan_map)
    cfg = PlannerConfig(asm="random")
    _, _, _, own = _first_decision(robot, m, replace(cfg, turn_edges=False), seed=5)
    _, _, view, both = _first_decision(robot, m, cfg, seed=5)
    assert isinstance(view, TurnedEdges) and len(both) > len(own)
    assert [a.edge for a in both[: len(own)]] == [a.edge for a in own]  # the map's own edges first
    assert all(a.turn == 0.0 for a in both[: len(own)]) and any(a.turn != 0.0 for a in both)


def test_the_paper_settings_turn_no_edges():
    assert PlannerConfig().turn_edges and not PlannerConfig().paper().turn_edges
    assert PlannerConfig().settings()["turn_edges"] is True


def test_the_planner_records_the_turn_of_the_edge_it_executes(robot, plan_map):
    """With every edge of the map over the target found futile there, the planner's action is
    a turned copy: the record names the map's edge and its turn, and the action's edge states
    are the map's edge's with J1 turned by it."""
    m = load_map(plan_map)
    cfg = PlannerConfig(asm="random")
    pl, obs, _, _ = _first_decision(robot, m, cfg, seed=5)
    target, half = obs.objects[0, :2], float(pl.sc.target.half[0])
    for e in edges_over_target(pl.bundle, pl.reach, target, half, cfg.target_margin):
        pl.futile[(int(e), 0)] = target.copy()
    action, rec = pl.choose(obs, np.random.default_rng(5))
    assert action is not None and action.turn != 0.0
    assert rec.edge == action.edge and rec.turn_deg == round(np.degrees(action.turn)) != 0
    assert rec.summary()["turn_deg"] == rec.turn_deg
    states = m.edges.edge(action.edge, ("q",))["q"].astype(np.float64)
    states[:, 0] += np.radians(rec.turn_deg)
    executed = action.q[action.transit_steps :]
    assert np.allclose(executed, states[action.edge_first : action.edge_first + len(executed)], atol=1e-6)
