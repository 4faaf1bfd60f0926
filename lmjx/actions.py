"""Actions: the transit from the robot's current configuration to an edge's start, then the
edge itself, as joint targets at the control rate; and the servo controls a simulator
applies at its physics rate.

The transit is a straight line in joint space, timed so that no joint exceeds half its
velocity limit; when that line would take the arm into the table or into itself (checked
with C MuJoCo at every control step), it goes through the failure's park pose instead; when
that too collides, the action is not possible from here.  Nothing here chooses actions.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from .bundle import Bundle
from .failure import Failure
from .robot import Robot

CONTROL_DT = 0.02  # the edges' control period [s]


@dataclass
class Action:
    """A planned action: joint targets q* and velocities qd* at the control rate."""

    edge: int  # edge id in the bundle
    q: np.ndarray  # (T, 7)
    qd: np.ndarray  # (T, 7)
    transit_steps: int  # the first transit_steps rows move to the edge's start
    via_park: bool

    @property
    def duration(self) -> float:
        return len(self.q) * CONTROL_DT


class TransitPlanner:
    """Builds collision-free joint-space transits for one failure."""

    def __init__(self, robot: Robot, failure: Failure, speed_fraction: float = 0.5) -> None:
        self.robot = robot
        self.failure = failure
        self.m = robot.mj
        self.d = mujoco.MjData(self.m)
        self.speed = speed_fraction * robot.qd_max
        self.park = park_pose(robot, failure)

    def colliding(self, q: np.ndarray) -> bool:
        self.d.qpos[:] = q
        mujoco.mj_kinematics(self.m, self.d)
        mujoco.mj_collision(self.m, self.d)
        return self.d.ncon > 0

    def segment(self, q0: np.ndarray, q1: np.ndarray) -> np.ndarray | None:
        """Joint targets (T, 7) from q0 (exclusive) to q1 (inclusive), or None if they collide."""
        dq = q1 - q0
        t = max(float(np.max(np.abs(dq) / self.speed)), 2 * CONTROL_DT)
        n = int(np.ceil(t / CONTROL_DT))
        path = q0 + np.outer(np.arange(1, n + 1) / n, dq)
        # check at least every 0.02 rad of the largest joint motion; a start already in contact
        # (the real arm pressed against the table) may move out of it, but not back in
        fine = max(n, int(np.ceil(np.max(np.abs(dq)) / 0.02)))
        leaving = self.colliding(q0)
        for s in np.arange(1, fine + 1) / fine:
            hit = self.colliding(q0 + s * dq)
            if hit and not leaving:
                return None
            leaving = leaving and hit
        return path

    def action(self, bundle: Bundle, edge: int, q_now: np.ndarray) -> Action | None:
        states = bundle.edge(edge)
        q_edge = states["q"].astype(np.float64)
        qd_edge = states["qd"].astype(np.float64)
        start = q_edge[0]
        via = False
        transit = self.segment(q_now, start)
        if transit is None:
            first = self.segment(q_now, self.park)
            second = self.segment(self.park, start) if first is not None else None
            if first is None or second is None:
                return None
            transit = np.concatenate([first, second])
            via = True
        qd_transit = np.gradient(np.concatenate([q_now[None], transit]), CONTROL_DT, axis=0)[1:]
        return Action(
            edge=edge,
            q=np.concatenate([transit, q_edge]),
            qd=np.concatenate([qd_transit, qd_edge]),
            transit_steps=len(transit),
            via_park=via,
        )


def park_pose(robot: Robot, failure: Failure, samples: int = 3000) -> np.ndarray:
    """A collision-free configuration with the arm raised clear of the table, for transits.

    Franka's ready pose with the locked joints at their angles, if collision-free; else, of
    `samples` seeded random collision-free configurations, the one whose hand is highest.
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
    hand = m.body("hand").id
    best, best_z = None, -np.inf
    for _ in range(samples):
        x = q.copy()
        x[free] = robot.lower[free] + rng.random(len(free)) * (robot.upper[free] - robot.lower[free])
        if free_of_contact(x) and d.xpos[hand][2] > best_z:
            best, best_z = x, d.xpos[hand][2]
    if best is None:
        raise RuntimeError(f"failure {failure.spec}: no collision-free configuration found for parking")
    return best


def controls(action: Action, physics_dt: float, settle: float) -> np.ndarray:
    """Servo controls (steps, 14) at the physics rate: q* interpolated linearly between
    control points, qd* held; then `settle` seconds holding the final pose."""
    sub = round(CONTROL_DT / physics_dt)
    q = np.concatenate([action.q[:1] - action.qd[:1] * CONTROL_DT, action.q])  # the point before the first
    frac = (np.arange(1, sub + 1) / sub)[None, :, None]
    q_phys = (q[:-1, None, :] * (1 - frac) + q[1:, None, :] * frac).reshape(-1, 7)
    qd_phys = np.repeat(action.qd, sub, axis=0)
    hold = round(settle / physics_dt)
    q_hold = np.repeat(action.q[-1:], hold, axis=0)
    out = np.zeros((len(q_phys) + hold, 14))
    out[: len(q_phys), :7] = q_phys
    out[: len(q_phys), 7:] = qd_phys
    out[len(q_phys) :, :7] = q_hold
    return out
