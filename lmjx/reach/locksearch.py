"""Lock search: Reach-Ability areas over a grid of lock angles for a set of locked joints.

Used to choose the named failure cases' lock angles (README.md) and to study how the angle
at which joints fail changes what the arm can still do.  Each grid point is a full
Reach-Ability map with every check (collisions, grasp clearance).
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass

import numpy as np

from lmjx.errors import ConfigError
from lmjx.model.failure import Failure, _check_angle
from lmjx.model.robot import Robot, load_robot
from lmjx.reach.reachability import ReachConfig, reach_config, reach_map
from lmjx.runtime.progress import Progress


@dataclass
class LockSearchResult:
    joints: tuple[int, ...]  # 1-based
    grids: tuple[np.ndarray, ...]  # angles per joint
    pm: np.ndarray  # areas, shape = grid sizes
    npm_pm: np.ndarray
    seconds: float

    def best(self) -> tuple[tuple[float, ...], float, float]:
        """The lock with the smallest PM area; ties broken by the largest NPM+PM area."""
        flat = [
            (self.pm[idx], -self.npm_pm[idx], idx) for idx in itertools.product(*(range(len(g)) for g in self.grids))
        ]
        pm, neg_npm, idx = min(flat)
        angles = tuple(float(self.grids[k][i]) for k, i in enumerate(idx))
        return angles, float(pm), float(-neg_npm)

    def closest(
        self, pm_ratio: float, npm_ratio: float, reference: dict[str, float]
    ) -> tuple[tuple[float, ...], float, float]:
        """The lock whose areas, relative to `reference` (the no-failure areas), are closest
        (least squares) to the target ratios; e.g. the paper's case 1: 0.62/0.85, 0.85/0.92."""
        best = None
        for idx in itertools.product(*(range(len(g)) for g in self.grids)):
            err = (self.pm[idx] / reference["pm"] - pm_ratio) ** 2 + (
                self.npm_pm[idx] / reference["npm_pm"] - npm_ratio
            ) ** 2
            if best is None or err < best[0]:
                best = (err, idx)
        assert best is not None
        idx = best[1]
        angles = tuple(float(self.grids[k][i]) for k, i in enumerate(idx))
        return angles, float(self.pm[idx]), float(self.npm_pm[idx])

    def rows(self) -> list[dict]:
        out = []
        for idx in itertools.product(*(range(len(g)) for g in self.grids)):
            out.append(
                {
                    **{
                        f"J{j}": round(float(self.grids[k][i]), 4)
                        for k, (j, i) in enumerate(zip(self.joints, idx, strict=True))
                    },
                    "pm_m2": round(float(self.pm[idx]), 4),
                    "npm_pm_m2": round(float(self.npm_pm[idx]), 4),
                }
            )
        return out


def parse_joints(text: str, robot: Robot) -> tuple[int, ...]:
    joints = []
    for part in text.split(","):
        name = part.strip().upper()
        if not name.startswith("J") or not name[1:].isdigit() or not 1 <= int(name[1:]) <= robot.nq:
            raise ConfigError(f"cannot read joint '{part.strip()}'; use e.g. --joints J6,J7 (joints J1..J{robot.nq})")
        joints.append(int(name[1:]))
    if len(set(joints)) != len(joints):
        raise ConfigError("a joint is listed twice in --joints")
    return tuple(joints)


def lock_grid(robot: Robot, joint: int, n: int, margin: float = 0.02) -> np.ndarray:
    """n angles spread evenly over a joint's range, `margin` rad inside each limit."""
    if n < 1:
        raise ConfigError(f"the grid needs at least one angle per joint, got {n}")
    lo, hi = robot.lower[joint - 1] + margin, robot.upper[joint - 1] - margin
    return np.array([(lo + hi) / 2]) if n == 1 else np.linspace(lo, hi, n)


def lock_search(
    joints: tuple[int, ...],
    grids: tuple[np.ndarray, ...],
    config: ReachConfig | None = None,
    robot: Robot | None = None,
    base: Failure | None = None,
    progress: bool = False,
) -> LockSearchResult:
    """Reach-Ability areas for every combination of lock angles in `grids`.

    `base` adds further locked joints held fixed over the whole search.
    """
    robot = robot or load_robot()
    config = dataclasses.replace(config or reach_config(robot), traced_locks=True)
    shape = tuple(len(g) for g in grids)
    pm = np.zeros(shape)
    npm = np.zeros(shape)
    seconds = 0.0
    base_locks = dict(base.locked) if base else {}
    bar = Progress(total=int(np.prod(shape)), desc="lock search", enabled=progress, unit="map")
    for idx in itertools.product(*(range(s) for s in shape)):
        locks = dict(base_locks)
        for k, i in enumerate(idx):
            _check_angle(robot, joints[k], float(grids[k][i]), "lock search")
            locks[joints[k]] = float(grids[k][i])
        locked = tuple(sorted(locks.items()))
        failure = Failure(",".join(f"J{j}={a:.4f}" for j, a in locked), locked, robot.nq)
        res = reach_map(failure, config, robot=robot)
        a = res.areas(smooth=True)
        pm[idx], npm[idx] = a["pm"], a["npm_pm"]
        seconds += res.seconds
        bar.update(1)
    bar.close()
    return LockSearchResult(joints, grids, pm, npm, seconds)
