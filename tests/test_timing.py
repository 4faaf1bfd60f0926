"""The transits' time law (`lmjx.timing`): against its speed law integrated numerically, and
executed by the "real" world's servos (C MuJoCo) around a corner, where the constant speed
it replaced overshoots."""

from __future__ import annotations

from itertools import pairwise

import mujoco
import numpy as np
import pytest

from lmjx.actions import CONTROL_DT, Action, TransitPlanner
from lmjx.executor import SimulatedRealWorld
from lmjx.failure import parse_failure
from lmjx.scenarios import sample_layout, scenario
from lmjx.timing import RAMP, ramp_time, ramped


def integrated_law(t: float, n: int, fine: int = 200_000) -> np.ndarray:
    """The fractions done at the n control steps, by integrating the speed law numerically:
    a half-cosine rise to the peak over r, the peak held, a half-cosine fall over r; peak and
    r from the constant-speed time t (the peak 1/t where the rise fits, else the rise and
    fall meeting at the same peak acceleration); stretched over the n steps."""
    r = RAMP if t >= RAMP else np.sqrt(t * RAMP)
    peak = 1.0 / max(t, r)
    total = t + RAMP if t >= RAMP else 2 * r
    x = np.linspace(0.0, total, fine + 1)
    v = np.full_like(x, peak)
    up, down = x < r, x > total - r
    v[up] = peak * (1 - np.cos(np.pi * x[up] / r)) / 2
    v[down] = peak * (1 - np.cos(np.pi * (total - x[down]) / r)) / 2
    s = np.concatenate([[0.0], np.cumsum((v[1:] + v[:-1]) / 2 * np.diff(x))])
    return np.interp(np.arange(1, n + 1) * total / n, x, s)


@pytest.mark.parametrize("t", [0.04, 0.1, RAMP, 0.7, 2.3])
def test_ramped_matches_its_speed_law_integrated_and_rests_at_both_ends(t):
    n = int(np.ceil(ramp_time(t) / CONTROL_DT - 1e-9))
    s = ramped(t, n)
    ref = integrated_law(t, n)
    assert ref[-1] == pytest.approx(1.0, abs=1e-6)  # the law covers the piece
    np.testing.assert_allclose(s, ref, atol=1e-6)
    assert s[-1] == 1.0 and np.all(np.diff(s) >= 0)
    rate = np.diff(np.concatenate([[0.0], s])) / CONTROL_DT
    assert rate.max() <= 1.0 / t + 1e-9  # never faster than the constant speed it replaces
    assert rate[0] < 0.5 * rate.max() and rate[-1] < 0.5 * rate.max()  # from rest, to rest
    assert n * CONTROL_DT < ramp_time(t) + CONTROL_DT


def _body_deviation(robot, planned_path: np.ndarray, real_q: np.ndarray) -> float:
    """The largest distance [m] of any body's origin on the real arm from that body's path
    when the arm follows `planned_path` (densely sampled joint-space polyline)."""
    m, d = robot.mj, mujoco.MjData(robot.mj)

    def origins(qs):
        out = np.zeros((len(qs), m.nbody - 1, 3))
        for i, q in enumerate(qs):
            d.qpos[:] = q
            mujoco.mj_kinematics(m, d)
            out[i] = d.xpos[1:]
        return out

    plan, real = origins(planned_path), origins(real_q)
    return float(np.sqrt(((real[:, None] - plan[None]) ** 2).sum(-1)).min(axis=1).max())


def test_a_transit_stops_at_its_corner_and_the_real_arm_follows_it(robot):
    """A transit of two straight pieces turning sharply (built by the planner's own
    `segments`), executed by the "real" world's servos: the arm comes to rest at the corner
    and keeps within a few millimetres of the planned path, where the same pieces at
    constant speed (the ninth session's law) overshoot the turn by about twice as much."""
    failure = parse_failure("case2", robot)
    tp = TransitPlanner(robot, failure)
    free = list(failure.free(robot.nq))
    rng = np.random.default_rng(1)
    verts = []
    for _ in range(4):  # the fourth of these seeded corners (its overshoot the largest at constant speed)
        d1, d2 = np.zeros(robot.nq), np.zeros(robot.nq)
        d1[free], d2[free] = rng.uniform(-0.6, 0.6, len(free)), rng.uniform(-0.6, 0.6, len(free))
        verts = np.clip(np.array([tp.park, tp.park + d1, tp.park + d1 + d2]), robot.lower + 0.05, robot.upper - 0.05)
    legs = tp.segments(verts[:-1], verts[1:])
    assert all(leg is not None for leg in legs)
    ramped_q = np.concatenate(legs)
    corner = len(legs[0]) - 1
    assert np.allclose(ramped_q[corner], verts[1])
    constant = []
    for a, b in pairwise(verts):
        k = int(np.ceil(np.max(np.abs(b - a) / tp.speed) / CONTROL_DT))
        constant.append(a + np.outer(np.arange(1, k + 1) / k, b - a))
    constant_q = np.concatenate(constant)
    dense = np.concatenate([a + np.linspace(0, 1, 300)[:, None] * (b - a) for a, b in pairwise(verts)])
    layout = sample_layout(scenario(3, tasks="hard"), 0)

    def execute(targets: np.ndarray) -> tuple[float, float]:
        world = SimulatedRealWorld(robot, 0, settle=0.3)
        world.reset(layout, verts[0])
        seen: list[np.ndarray] = []
        world.on_step = lambda m, d: seen.append(d.qpos[world.scene.robot_qpos].copy())
        qd = np.gradient(np.concatenate([verts[0][None], targets]), CONTROL_DT, axis=0)[1:]
        action = Action(edge=0, q=targets, qd=qd, transit_steps=len(targets), via_park=False, route="test")
        world.execute(action)
        return _body_deviation(robot, dense, np.asarray(seen)[::2]), float(np.abs(qd[corner]).max())

    dev_ramped, qd_corner = execute(ramped_q)
    dev_constant, qd_constant = execute(constant_q)
    assert qd_corner < 0.05 * qd_constant  # at rest at the corner (as commanded)
    assert dev_ramped < 0.6 * dev_constant, (dev_ramped, dev_constant)
    assert dev_ramped < 0.012, dev_ramped
