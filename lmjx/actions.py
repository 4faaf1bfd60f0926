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
    q: np.ndarray  # (T, nq)
    qd: np.ndarray  # (T, nq)
    transit_steps: int  # the first transit_steps rows move to the edge's start
    via_park: bool

    @property
    def duration(self) -> float:
        return len(self.q) * CONTROL_DT


class TransitPlanner:
    """Builds collision-free joint-space transits for one failure.

    Collisions are checked one configuration at a time with C MuJoCo, or, with `batched`,
    every configuration of many candidate transits at once with lmjx's clearance kernel
    (`kernels.collision.arm_clearance`, on the accelerator JAX uses): the same checks
    (tests/test_planning.py compares the two), for planners that build thousands of
    actions per decision.  Transits through the park pose are remembered per edge: the
    park-to-start half does not depend on where the arm is.
    """

    def __init__(self, robot: Robot, failure: Failure, speed_fraction: float = 0.5, batched: bool = False) -> None:
        self.robot = robot
        self.failure = failure
        self.m = robot.mj
        self.d = mujoco.MjData(self.m)
        self.speed = speed_fraction * robot.qd_max
        self.park = park_pose(robot, failure)
        self.batched = batched
        self._kernel = None
        self._from_park: dict[tuple[int, int], np.ndarray | None] = {}  # (bundle id, edge) -> park -> start

    def colliding(self, q: np.ndarray) -> bool:
        self.d.qpos[:] = q
        mujoco.mj_kinematics(self.m, self.d)
        mujoco.mj_collision(self.m, self.d)
        return self.d.ncon > 0

    def colliding_batch(self, qs: np.ndarray) -> np.ndarray:
        """(n,) whether each configuration of qs (n, nj) penetrates the table or the arm."""
        if not self.batched:
            return np.array([self.colliding(q) for q in qs], bool)
        if self._kernel is None:
            self._kernel = _clearance_kernel(self.robot)
        out = self._kernel.run(np.asarray(qs, np.float32))
        return (out["self_clearance"] < 0) | (out["table_clearance"] < 0)

    def _timing(self, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Control steps (n,) of straight transits dq (n, nj), and collision checks along them:
        at least one per control step and one per 0.02 rad of the largest joint motion."""
        span = np.max(np.abs(dq), axis=-1)
        t = np.maximum(np.max(np.abs(dq) / self.speed, axis=-1), 2 * CONTROL_DT)
        n = np.ceil(t / CONTROL_DT).astype(int)
        fine = np.maximum(n, np.ceil(span / 0.02).astype(int))
        return n, fine

    def segment(self, q0: np.ndarray, q1: np.ndarray) -> np.ndarray | None:
        """Joint targets (T, nq) from q0 (exclusive) to q1 (inclusive), or None if they collide."""
        return self.segments(q0[None], q1[None])[0]

    def segments(self, q0: np.ndarray, q1: np.ndarray) -> list[np.ndarray | None]:
        """`segment` for many pairs (n, nj): all their configurations checked in one batch.
        A start already in contact (the real arm pressed against the table) may move out of
        it, but not back in."""
        if not self.batched:
            return [self._segment_one(a, b) for a, b in zip(q0, q1, strict=True)]
        dq = q1 - q0
        n, fine = self._timing(dq)
        owner = np.repeat(np.arange(len(q0)), fine)
        first = np.concatenate([[0], np.cumsum(fine)[:-1]])
        k = np.arange(len(owner)) - first[owner] + 1
        s = k / fine[owner]
        points = q0[owner] + s[:, None] * dq[owner]
        hits = self.colliding_batch(np.concatenate([q0, points]))
        start_hit, hits = hits[: len(q0)], hits[len(q0) :]
        # a check fails when it hits after any free check (the start's included)
        out: list[np.ndarray | None] = []
        for i in range(len(q0)):
            h = hits[first[i] : first[i] + fine[i]]
            free = ~np.concatenate([[start_hit[i]], h[:-1]])
            free_before = np.logical_or.accumulate(free)
            if np.any(h & free_before):
                out.append(None)
            else:
                out.append(q0[i] + np.outer(np.arange(1, n[i] + 1) / n[i], dq[i]))
        return out

    def _segment_one(self, q0: np.ndarray, q1: np.ndarray) -> np.ndarray | None:
        """`segment` checked with C MuJoCo, stopping at the first collision."""
        dq = q1 - q0
        n, fine = (int(x[0]) for x in self._timing(dq[None]))
        leaving = self.colliding(q0)
        for s in np.arange(1, fine + 1) / fine:
            hit = self.colliding(q0 + s * dq)
            if hit and not leaving:
                return None
            leaving = leaving and hit
        return q0 + np.outer(np.arange(1, n + 1) / n, dq)

    def action(self, bundle: Bundle, edge: int, q_now: np.ndarray) -> Action | None:
        acts = self.actions(bundle, np.array([edge]), q_now, 1)
        return acts[0] if acts else None

    def actions(self, bundle: Bundle, edges: np.ndarray, q_now: np.ndarray, want: int) -> list[Action]:
        """The first `want` feasible actions among `edges`, in their order (fewer if there are
        not that many)."""
        out: list[Action] = []
        block = want if self.batched else 1
        i = 0
        while len(out) < want and i < len(edges):
            part = np.asarray(edges[i : i + block])
            i += len(part)
            starts = bundle.q_start[part].astype(np.float64)
            direct = self.segments(np.repeat(q_now[None], len(part), axis=0), starts)
            via = self._via_park(bundle, part, q_now, [j for j, p in enumerate(direct) if p is None])
            ok = [j for j in range(len(part)) if direct[j] is not None or j in via]
            bundle.prefetch(part[ok][: want - len(out)], ("q", "qd"))  # a lazily read map: at once
            for j, e in enumerate(part):
                transit = direct[j] if direct[j] is not None else via.get(j)
                if transit is None:
                    continue
                out.append(_action(bundle, int(e), q_now, transit, direct[j] is None))
                if len(out) == want:
                    break
            block = max(1, 2 * (want - len(out))) if self.batched else 1
        return out

    def _via_park(self, bundle: Bundle, part: np.ndarray, q_now: np.ndarray, idx: list[int]) -> dict[int, np.ndarray]:
        """Transits through the park pose for part[idx]: q_now -> park, then park -> start."""
        if not idx:
            return {}
        first = self.segment(q_now, self.park)
        if first is None:
            return {}
        key = id(bundle)
        todo = [j for j in idx if (key, int(part[j])) not in self._from_park]
        if todo:
            starts = bundle.q_start[part[todo]].astype(np.float64)
            for j, seg in zip(todo, self.segments(np.repeat(self.park[None], len(todo), axis=0), starts), strict=True):
                self._from_park[(key, int(part[j]))] = seg
        out = {}
        for j in idx:
            second = self._from_park[(key, int(part[j]))]
            if second is not None:
                out[j] = np.concatenate([first, second])
        return out


def _action(bundle: Bundle, edge: int, q_now: np.ndarray, transit: np.ndarray, via_park: bool) -> Action:
    states = bundle.edge(edge, ("q", "qd"))
    q_edge = states["q"].astype(np.float64)
    qd_edge = states["qd"].astype(np.float64)
    qd_transit = np.gradient(np.concatenate([q_now[None], transit]), CONTROL_DT, axis=0)[1:]
    return Action(
        edge=edge,
        q=np.concatenate([transit, q_edge]),
        qd=np.concatenate([qd_transit, qd_edge]),
        transit_steps=len(transit),
        via_park=via_park,
    )


def _clearance_kernel(robot: Robot):
    """jit(vmap(arm_clearance)) over chunks of configurations (JAX, compiled once)."""
    from .batching import ChunkedKernel, backend
    from .kernels.collision import arm_clearance

    unroll = backend() != "cpu"
    chunk = 1 << 16 if backend() != "cpu" else 4096

    def one(q):
        return arm_clearance(robot.arm, q, unroll)

    return ChunkedKernel(("arm_clearance", robot.model_hash, unroll), one, [], [(np.float32, (robot.nq,))], chunk)


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


def control_points(actions: list[Action]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The control points of several actions, padded to the longest: q* (n, T + 1, nj) with
    the point before the first (q - qd dt) in row 0, qd* (n, T, nj), and each action's
    number of control points (n,).  `controls` interpolates these; the GPU simulator does
    the same on the device."""
    n_pts = np.array([len(a.q) for a in actions], np.int32)
    nj = actions[0].q.shape[1]
    q = np.zeros((len(actions), int(n_pts.max()) + 1, nj))
    qd = np.zeros((len(actions), int(n_pts.max()), nj))
    for i, a in enumerate(actions):
        q[i, 0] = a.q[0] - a.qd[0] * CONTROL_DT
        q[i, 1 : len(a.q) + 1] = a.q
        q[i, len(a.q) + 1 :] = a.q[-1]
        qd[i, : len(a.q)] = a.qd
    return q, qd, n_pts


def controls(action: Action, physics_dt: float, settle: float) -> np.ndarray:
    """Servo controls (steps, 2 nj) at the physics rate: q* interpolated linearly between
    control points, qd* held; then `settle` seconds holding the final pose."""
    sub = round(CONTROL_DT / physics_dt)
    q = np.concatenate([action.q[:1] - action.qd[:1] * CONTROL_DT, action.q])  # the point before the first
    frac = (np.arange(1, sub + 1) / sub)[None, :, None]
    nj = q.shape[1]
    q_phys = (q[:-1, None, :] * (1 - frac) + q[1:, None, :] * frac).reshape(-1, nj)
    qd_phys = np.repeat(action.qd, sub, axis=0)
    hold = round(settle / physics_dt)
    q_hold = np.repeat(action.q[-1:], hold, axis=0)
    out = np.zeros((len(q_phys) + hold, 2 * nj))
    out[: len(q_phys), :nj] = q_phys
    out[: len(q_phys), nj:] = qd_phys
    out[len(q_phys) :, :nj] = q_hold
    return out
