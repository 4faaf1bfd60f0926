"""The greedy planner's navigation function against closed-form shortest paths."""

import math

import numpy as np
import pytest

from lmjx.sim.goalfield import GoalField
from lmjx.sim.scenarios import scenario

LO, HI = np.array([-0.5, -1.1]), np.array([1.2, 1.1])


def test_open_table_is_euclidean():
    sc = scenario(1, tasks="hard")
    f = GoalField(sc, LO, HI)
    pts = np.random.default_rng(0).uniform([0.1, -0.4], [0.8, 0.6], (200, 2))
    np.testing.assert_allclose(f(pts), np.hypot(*(pts - sc.goal_center).T), atol=1e-12)


def test_path_around_the_tunnel_wall():
    sc = scenario(2, tasks="hard")
    f = GoalField(sc, LO, HI)
    wall = next(b for b in sc.fixed if b.name == "wall_near")
    g = math.hypot(sc.target.half[0], sc.target.half[1])  # the cube's centre keeps this far
    corner = np.array([wall.x + wall.half[0] + g, wall.y + wall.half[1] + g])
    goal = np.array(sc.goal_center)
    p = np.array([0.15, 0.30])  # behind the wall, left of the opening
    exact = np.linalg.norm(p - corner) + np.linalg.norm(corner - goal)
    assert exact > np.linalg.norm(p - goal) + 0.02  # the wall is in the way
    v = float(f(p))
    assert exact - 0.005 <= v <= exact * 1.085  # 8-connected grid: at most ~8 % longer
    # straight through the opening: the plain distance, up to the grid's error
    q = np.array([0.47, 0.45])
    assert np.linalg.norm(q - goal) - 0.005 <= float(f(q)) <= np.linalg.norm(q - goal) * 1.085


def test_inside_a_wall_costs_more_than_beside_it():
    sc = scenario(2, tasks="hard")
    f = GoalField(sc, LO, HI)
    wall = next(b for b in sc.fixed if b.name == "wall_far")
    inside = np.array([wall.x, wall.y])
    beside = np.array([wall.x, wall.y + wall.half[1] + 0.05])
    assert np.isfinite(f(inside)) and f(inside) > f(beside)


def test_weights_scale_the_path_cost():
    """A constant weight w makes every free cell's value w times the path length."""
    sc = scenario(2, tasks="hard")
    f = GoalField(sc, LO, HI)
    g = GoalField(sc, LO, HI, weights=lambda p: np.full(len(p), 3.0))
    pts = np.random.default_rng(1).uniform([0.1, -0.4], [0.8, 0.6], (400, 2))
    pts = pts[np.abs(pts[:, 1] - 0.26) > 0.08]  # away from the wall's cells
    np.testing.assert_allclose(g(pts), 3.0 * f(pts), rtol=1e-9)


def test_a_band_of_weight_costs_its_width_times_the_weight():
    """Open table, a band x > 0.6 weighted 5: from a point level with the goal, beyond the
    band's edge, the cost is 5 x its way in the band plus the rest (the grid's axis is exact;
    the step across the band's edge takes the mean weight)."""
    sc = scenario(1, tasks="hard")
    gx, gy = sc.goal_center
    g = GoalField(sc, LO, HI, weights=lambda p: np.where(p[:, 0] > 0.6, 5.0, 1.0))
    for x in (0.7, 0.85, 1.0):
        exact = 5.0 * (x - 0.6) + (0.6 - gx)
        assert float(g(np.array([x, gy]))) == pytest.approx(exact, abs=2 * 0.005 * 4)
    assert float(g(np.array([gx - 0.2, gy]))) == pytest.approx(0.2, abs=1e-6)  # outside the band: the distance
