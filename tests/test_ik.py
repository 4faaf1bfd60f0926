"""IK kernels: round trips, locked joints, limits, acceptance re-verified in C MuJoCo.  Every
test runs the Reach-Ability map's program of its failure (`conftest.ik_batch`: its sites,
the TCP first, its settings and launch size), the program the maps and edges run."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from conftest import ik_batch, random_configs

from lmjx.model.failure import parse_failure

TCP, HAND, WRIST = 0, 1, 2  # indices into the program's sites


def _reachable_targets(robot, site, n, seed):
    """Positions of `site` at random collision-free configurations (reachable by construction)."""
    m = robot.mj
    d = mujoco.MjData(m)
    out = []
    for q in random_configs(robot, 20 * n, seed):
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        if d.ncon == 0 and d.site_xpos[site][2] > 0.02:
            out.append(d.site_xpos[site].copy())
        if len(out) == n:
            break
    return np.array(out)


def _verify_in_mujoco(robot, failure, res, targets, site_ids, pm):
    """Re-check every accepted solution with C MuJoCo in float64."""
    m = robot.mj
    d = mujoco.MjData(m)
    q_fixed = failure.q_fixed()
    locked = [j - 1 for j in failure.locked_joints]
    for i in np.nonzero(res["ok"])[0]:
        q = res["q"][i].astype(np.float64)
        assert np.all(q >= robot.lower - 1e-6) and np.all(q <= robot.upper + 1e-6)
        assert np.array_equal(res["q"][i][locked], q_fixed[locked].astype(np.float32))
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        assert d.ncon == 0, "accepted solution in contact"
        p = d.site_xpos[site_ids[i]]
        x, y, zlo, zhi = targets[i]
        err = np.hypot(p[0] - x, p[1] - y)
        err = np.hypot(err, p[2] - np.clip(p[2], zlo, zhi))
        assert err <= 0.002 + 1e-5
        if pm[i]:
            assert d.site_xmat[robot.tcp_site].reshape(3, 3)[2, 2] <= 1e-6  # tool z at or below horizontal


def test_round_trip_position_ik(robot):
    """q -> FK -> IK -> FK: targets of the hand at random collision-free poses are found."""
    failure = parse_failure("none", robot)
    site = robot.interaction_points["hand"]
    pts = _reachable_targets(robot, site, 150, seed=1)
    n, m_restarts = len(pts), 8
    targets = np.concatenate([pts[:, :2], pts[:, 2:], pts[:, 2:]], axis=1).repeat(m_restarts, 0)
    batch = ik_batch(robot, failure)
    assert batch.sites[HAND] == site
    rng = np.random.default_rng(0)
    q0 = (robot.lower + rng.random((len(targets), 7)) * (robot.upper - robot.lower)).astype(np.float32)
    res = batch.solve(targets, np.full(len(targets), HAND, np.int32), np.zeros(len(targets), bool), q0)
    found = res["ok"].reshape(n, m_restarts).any(axis=1)
    assert found.mean() >= 0.95
    _verify_in_mujoco(robot, failure, res, targets, np.full(len(targets), site), np.zeros(len(targets), bool))


@pytest.mark.parametrize("name, spec", [("panda", "case1"), ("panda", "case2"), ("ur5e", "case1")])
def test_locked_joints_limits_and_acceptance(name, spec):
    from lmjx.model.robot import load_robot

    robot = load_robot(name)
    failure = parse_failure(spec, robot)
    batch = ik_batch(robot, failure)
    sites = batch.sites[:3]  # the TCP, the hand, the wrist
    rng = np.random.default_rng(2)
    n = 1536
    xy = np.stack([rng.uniform(0.1, 1.0, n), rng.uniform(-0.6, 0.6, n)], axis=1)
    which = rng.integers(0, 3, n)
    pm = which == 0
    rad = robot.arm.site_radius[list(sites)][which]
    zlo = np.where(pm, 0.025, rad)
    zhi = np.where(pm, 0.025, rad + 0.035)
    targets = np.concatenate([xy, zlo[:, None], zhi[:, None]], axis=1)
    free = failure.free()
    q0 = (robot.lower[list(free)] + rng.random((n, len(free))) * (robot.upper - robot.lower)[list(free)]).astype(
        np.float32
    )
    res = batch.solve(targets, which.astype(np.int32), pm, q0)
    locked = [j - 1 for j in failure.locked_joints]
    # Locked joints stay exactly at their values and limits hold, for every result.
    assert np.array_equal(
        res["q"][:, locked], np.broadcast_to(failure.q_fixed()[locked].astype(np.float32), (n, len(locked)))
    )
    assert np.all(res["q"] >= robot.lower.astype(np.float32) - 1e-6)
    assert np.all(res["q"] <= robot.upper.astype(np.float32) + 1e-6)
    assert res["ok"].sum() > 50
    _verify_in_mujoco(robot, failure, res, targets, np.array(sites)[which], pm)


def test_pm_rejects_tool_pointing_up(robot):
    """A PM target reachable only with the tool pointing up is rejected; as NPM it is found."""
    failure = parse_failure("none", robot)
    # Straight above the shoulder, higher than the arm can reach tool-down.
    target = np.array([[0.0, 0.0, 1.18, 1.18]])
    rng = np.random.default_rng(0)
    q0 = (robot.lower + rng.random((64, 7)) * (robot.upper - robot.lower)).astype(np.float32)
    batch = ik_batch(robot, failure)
    assert batch.sites[TCP] == robot.tcp_site
    t = np.repeat(target, 64, axis=0)
    pm = batch.solve(t, np.full(64, TCP, np.int32), np.ones(64, bool), q0)
    npm = batch.solve(t, np.full(64, TCP, np.int32), np.zeros(64, bool), q0)
    assert not pm["ok"].any()
    assert npm["ok"].any()
    assert np.all(npm["tool_z"][npm["ok"]] > 0)


def test_same_inputs_same_results(robot):
    failure = parse_failure("case2", robot)
    rng = np.random.default_rng(4)
    t = np.concatenate([rng.uniform(0.2, 0.7, (300, 2)), np.full((300, 2), 0.025)], axis=1)
    q0 = (robot.lower[:5] + rng.random((300, 5)) * (robot.upper - robot.lower)[:5]).astype(np.float32)
    site, pm = np.full(300, TCP, np.int32), np.ones(300, bool)
    a = ik_batch(robot, failure).solve(t, site, pm, q0)
    b = ik_batch(robot, failure).solve(t, site, pm, q0)
    for k in a:
        assert np.array_equal(a[k], b[k])
