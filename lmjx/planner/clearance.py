"""The checks of a transit's straight joint-space segments against the table, the arm itself
and the scene's boxes at their margins (`lmjx.sim.sceneboxes`: the scene and the checks of
single configurations), leaving a margin it starts in without going deeper; and the
failure's park pose, the arm raised clear of the table, where transits that cannot go
straight retreat to.
"""

from __future__ import annotations

import mujoco
import numpy as np

from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.sim.sceneboxes import SceneClearance
from lmjx.types import CONTROL_DT

JAM_MARGIN = 0.004  # the first leg of a way out of a jam (`to_park`) keeps this far from movable objects [m]
LEAVE_TOLERANCE = 0.0002  # a transit leaving a contact may come this much nearer than it began [m] (kernel noise)
NEAR_SPEED = 0.1  # inside the margins the arm moves at this fraction of the transits' speed


def park_pose(robot: Robot, failure: Failure, samples: int = 3000) -> np.ndarray:
    """A collision-free configuration with the arm raised clear of the table, for transits.

    The robot's ready pose (`lmjx_ready`) with the locked joints at their angles, if
    collision-free; else, of `samples` seeded random collision-free configurations, the one
    whose tool (the body of the `tcp` site) is highest.
    """
    m = robot.mj
    d = mujoco.MjData(m)
    q = robot.ready.copy()
    for j, a in failure.locked:
        q[j - 1] = a

    def free_of_contact(x: np.ndarray) -> bool:
        d.qpos[:] = x
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        return d.ncon == 0

    if free_of_contact(q):
        return q
    rng = np.random.default_rng(0)
    free = list(failure.free(robot.nq))
    hand = int(m.site_bodyid[robot.tcp_site])
    best, best_z = None, -np.inf
    for _ in range(samples):
        x = q.copy()
        x[free] = robot.lower[free] + rng.random(len(free)) * (robot.upper[free] - robot.lower[free])
        if free_of_contact(x) and d.xpos[hand][2] > best_z:
            best, best_z = x, d.xpos[hand][2]
    if best is None:
        raise RuntimeError(f"failure {failure.spec}: no collision-free configuration found for parking")
    return best


class SceneChecks(SceneClearance):
    """The checks of straight joint-space segments against the table, the arm itself and the
    scene set (`TransitPlanner.set_scene`), on top of the checks of configurations
    (`SceneClearance`).  A part of `TransitPlanner`, which holds the state these read."""

    @staticmethod
    def _leaves_cleanly(start: np.ndarray, slacks: np.ndarray) -> bool:
        """Whether a path of checks with `slacks` (m, nb), from a start with `start` (nb,),
        enters no box's margin and, inside one at the start, never goes LEAVE_TOLERANCE
        deeper into it nor comes back once out; and ends outside every margin."""
        if not slacks.shape[1]:
            return True
        was_out = np.logical_or.accumulate(np.vstack([start[None] >= 0, slacks[:-1] >= 0]), axis=0)
        bad = (slacks < 0) & (was_out | (slacks < start[None] - LEAVE_TOLERANCE))
        return not bad.any() and bool(slacks[-1].min() >= 0)

    def segment_steps(self, dq: np.ndarray, slow: np.ndarray | bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Control steps (n,) of straight transits dq (n, nj), and collision checks along them:
        at least one per control step and one per 0.02 rad of the largest joint motion.
        `slow` (per transit): at NEAR_SPEED of the transits' speed (they begin inside the
        scene's margins, where the real arm's tracking error at full speed, up to 8 mm on
        calibration trials, turns near misses into contacts)."""
        span = np.max(np.abs(dq), axis=-1)
        speed = np.where(np.asarray(slow)[..., None], NEAR_SPEED, 1.0) * self.speed
        t = np.maximum(np.max(np.abs(dq) / speed, axis=-1), 2 * CONTROL_DT)
        n = np.ceil(t / CONTROL_DT).astype(int)
        fine = np.maximum(n, np.ceil(span / 0.02).astype(int))
        return n, fine

    def segment(self, q0: np.ndarray, q1: np.ndarray) -> np.ndarray | None:
        """Joint targets (T, nq) from q0 (exclusive) to q1 (inclusive), or None if blocked."""
        return self.segments(q0[None], q1[None])[0]

    def segments(self, q0: np.ndarray, q1: np.ndarray) -> list[np.ndarray | None]:
        """`segment` for many pairs (n, nj): all their configurations checked in one batch.
        A start already in contact (the real arm pressed against the table or an object) may
        move out of it, but not back in; a start inside an object's margin may leave it,
        never going deeper, never entering another's (`_leaves_cleanly`, box by box), and
        does so at NEAR_SPEED; the end must be free."""
        if not len(q0):
            return []
        dq = q1 - q0
        start_slack = self.scene_slacks(q0)
        n, fine = self.segment_steps(dq, (start_slack.min(axis=1, initial=np.inf) < 0) | (self._relax > 0))
        owner = np.repeat(np.arange(len(q0)), fine)
        first = np.concatenate([[0], np.cumsum(fine)[:-1]])
        k = np.arange(len(owner)) - first[owner] + 1
        s = k / fine[owner]
        points = q0[owner] + s[:, None] * dq[owner]
        both = np.concatenate([q0, points])
        slack = self.scene_slacks(points)
        hits = self.colliding_batch(both)
        start_hit, hits = hits[: len(q0)], hits[len(q0) :]
        # a check fails when it hits the table or the arm after any free check (the start's
        # included), or breaks `_leaves_cleanly` against the scene
        out: list[np.ndarray | None] = []
        for i in range(len(q0)):
            h = hits[first[i] : first[i] + fine[i]]
            free = ~np.concatenate([[start_hit[i]], h[:-1]])
            free_before = np.logical_or.accumulate(free)
            if (
                h[-1]
                or np.any(h & free_before)
                or not self._leaves_cleanly(start_slack[i], slack[first[i] : first[i] + fine[i]])
            ):
                out.append(None)
            else:
                out.append(q0[i] + np.outer(np.arange(1, n[i] + 1) / n[i], dq[i]))
        return out
