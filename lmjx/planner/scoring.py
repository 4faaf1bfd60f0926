"""How the planner scores a scene state: the target's way to the goal (the straight distance,
the path length around the fixed obstacles, or that path weighted by where the map can
push), with penalties for objects off the table; and the observed starts Greedy's
rescoring draws.
"""

from __future__ import annotations

import numpy as np

from lmjx.mapfile.bundle import Bundle
from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.reach.reachability import ReachResult
from lmjx.sim.goalfield import GoalField
from lmjx.sim.scenarios import Scenario
from lmjx.types import RESCORE_POS_NOISE, RESCORE_YAW_NOISE, PlannerConfig

OFF_TABLE_PENALTY = 1.0  # [m] per object that leaves the table
TARGET_LOST = 10.0  # [m] when the target leaves the table


class _Straight:
    """The straight distance to the goal's centre (the paper's score), called as a GoalField."""

    def __init__(self, sc: Scenario) -> None:
        self.sc = sc

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        return goal_distance(self.sc, np.asarray(xy))


def _score_field(
    robot: Robot, failure: Failure, reach: ReachResult, bundle: Bundle, sc: Scenario, cfg: PlannerConfig
) -> GoalField | _Straight:
    """What Greedy and Lazy call "closest" (`PlannerConfig.path_score`, `push_weight`).  The
    push counts a weight needs: the map's own (stored when it was built), else those of the
    cache folder, else computed and kept there (`lmjx.mapfile.pushmap`)."""
    if not cfg.path_score:
        return _Straight(sc)
    lo, hi = table_bounds(robot)
    if cfg.push_weight <= 0.0 or cfg.asm == "random":  # (Random scores nothing: no counts for it)
        return GoalField(sc, lo, hi)
    from lmjx.mapfile.pushmap import bundle_memo, counts_for
    from lmjx.planner.pushfield import push_weights

    memo = bundle_memo(bundle)  # the weighted field, once per bundle, scenario and weight
    key = ("field", sc, cfg.push_weight, cfg.target_margin)
    if key not in memo:
        plain = GoalField(sc, lo, hi)
        counts, _ = counts_for(robot, failure, bundle, reach, sc, plain)
        radius = float(sc.target.half[0]) + cfg.target_margin
        memo[key] = GoalField(sc, lo, hi, weights=push_weights(counts, reach, radius, cfg.push_weight))
    return memo[key]


def goal_distance(sc: Scenario, xy: np.ndarray) -> np.ndarray:
    """Distance (...,) from points (..., 2) to the goal region's centre."""
    return np.hypot(xy[..., 0] - sc.goal_center[0], xy[..., 1] - sc.goal_center[1])


def table_bounds(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    arm = robot.arm
    return arm.table_center[:2] - arm.table_half[:2], arm.table_center[:2] + arm.table_half[:2]


def score(sc: Scenario, robot: Robot, objects: np.ndarray, field: GoalField | None = None) -> np.ndarray:
    """Lower is better: the target's path length to the goal around the fixed obstacles
    (`GoalField`), plus penalties for objects that leave the table.  objects: (..., n, 7)."""
    lo, hi = table_bounds(robot)
    field = field or GoalField(sc, lo, hi)
    xy = objects[..., :2]
    off = (objects[..., 2] < robot.arm.table_z - 0.02) | np.any((xy < lo) | (xy > hi), axis=-1)
    s = field(objects[..., 0, :2])
    s = s + OFF_TABLE_PENALTY * off[..., 1:].sum(axis=-1)
    return np.where(off[..., 0], TARGET_LOST, s)


def _finite_m(x: float) -> float | None:
    """A score for the records: metres to 0.1 mm, None where not finite (JSON has no infinity)."""
    return round(float(x), 4) if np.isfinite(x) else None


def drawn_starts(objects: np.ndarray, k: int, rng: np.random.Generator, resting_z: np.ndarray) -> np.ndarray:
    """k copies (k, n, 7) of the observed objects (n, 7), each object's x, y and yaw redrawn
    about what was observed with the observation noise (RESCORE_POS_NOISE, RESCORE_YAW_NOISE).
    An object seen more than 1 cm off its resting height `resting_z` (n,) (fallen, lifted or
    off the table: how the "real" world's observation tells them, `executor.observe`) keeps
    its pose as seen."""
    out = np.repeat(objects[None].astype(np.float64), k, axis=0)
    n = len(objects)
    upright = np.abs(objects[:, 2] - resting_z) < 0.01
    dxy = rng.normal(0.0, RESCORE_POS_NOISE, (k, n, 2))
    dyaw = rng.normal(0.0, RESCORE_YAW_NOISE, (k, n))
    yaw = 2.0 * np.arctan2(objects[:, 6], objects[:, 3])  # (an upright object is seen turned about z only)
    out[:, :, :2] += np.where(upright[None, :, None], dxy, 0.0)
    new_yaw = yaw[None] + dyaw
    out[:, :, 3] = np.where(upright[None], np.cos(new_yaw / 2), out[:, :, 3])
    out[:, :, 4:6] = np.where(upright[None, :, None], 0.0, out[:, :, 4:6])
    out[:, :, 6] = np.where(upright[None], np.sin(new_yaw / 2), out[:, :, 6])
    return out
