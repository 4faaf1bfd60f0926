"""What a transit must keep clear of: the planner's scene as boxes at their observed poses,
the margins kept from movable objects and fixed obstacles, and the checks of arm
configurations against the table, the arm itself and the scene (C MuJoCo one at a time, or
lmjx's clearance kernels batched over many).  Also the failure's park pose, the arm raised
clear of the table, where transits that cannot go straight retreat to.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.sim.scene import yaw_quat
from lmjx.types import CONTROL_DT

OBJECT_MARGIN = 0.01  # a transit keeps this far from every movable object [m]
FIXED_MARGIN = 0.02  # ... and this far from every fixed obstacle [m]
JAM_MARGIN = 0.004  # the first leg of a way out of a jam (`to_park`) keeps this far from movable objects [m]
LEAVE_TOLERANCE = 0.0002  # a transit leaving a contact may come this much nearer than it began [m] (kernel noise)
NEAR_SPEED = 0.1  # inside the margins the arm moves at this fraction of the transits' speed
MAX_BOXES = 16  # boxes of a scene in one clearance program (padded)
EDGE_BOXES = 4  # the target and up to three fixed obstacles, in the program testing edges' states
MIN_EDGE_STATES = 5  # an edge cut short at a fixed obstacle keeps at least this many states (0.1 s)
SMALL_CHUNK = 64  # configurations per call of the planner's clearance programs on the CPU
BOUND_CHUNK = 256  # configurations per call of the lower bound's program on the CPU (`lower_bounds`)
BOUND_SLACK = 1e-5  # [m] taken off the float32 lower bound: a bound never above the exact clearance


@dataclass
class SceneBoxes:
    """The planner's scene as boxes: the movable objects at their observed poses and the
    fixed obstacles (the table and the arm itself are checked apart)."""

    names: tuple[str, ...]
    movable: np.ndarray  # (nb,) bool
    centers: np.ndarray  # (nb, 3)
    rots: np.ndarray  # (nb, 3, 3) world from box
    halves: np.ndarray  # (nb, 3)

    def margins(self) -> np.ndarray:
        return np.where(self.movable, OBJECT_MARGIN, FIXED_MARGIN)

    def padded(self, n: int = MAX_BOXES, which: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(centres, rotations, half sizes) of `n` boxes, float32: the scene's (or those
        `which` lists), then boxes of no size far below the table."""
        which = np.arange(len(self.names)) if which is None else np.asarray(which)
        nb = len(which)
        if nb > n:
            raise ValueError(f"a scene of {nb} boxes: the clearance program holds {n}")
        c = np.zeros((n, 3), np.float32)
        c[nb:, 2] = -100.0
        r = np.tile(np.eye(3, dtype=np.float32), (n, 1, 1))
        h = np.zeros((n, 3), np.float32)
        c[:nb], r[:nb], h[:nb] = self.centers[which], self.rots[which], self.halves[which]
        return c, r, h

    def bound_inputs(self, n: int = MAX_BOXES) -> tuple[np.ndarray, np.ndarray]:
        """(centres, circumradii) of `n` box slots, float32, for the lower bound's program:
        the scene's boxes, then points far below the table."""
        c, _, h = self.padded(n)
        return c, np.linalg.norm(h, axis=1).astype(np.float32)


def bound_kernel(robot: Robot, inputs: tuple[np.ndarray, np.ndarray]):
    """jit(vmap(boxes_lower_bound)) over chunks of configurations, the scene's box centres and
    circumradii shared (`SceneBoxes.bound_inputs`: one program for every scene of as many
    slots)."""
    from kernels.collision import boxes_lower_bound
    from lmjx.runtime.batching import ChunkedKernel, backend

    chunk = 1 << 14 if backend() != "cpu" else BOUND_CHUNK

    def one(centers, radii, q):
        return boxes_lower_bound(robot.arm, q, centers, radii)

    return ChunkedKernel(("boxes_lower_bound", robot.model_hash, len(inputs[0])), one, list(inputs),
                         [(np.float32, (robot.nq,))], chunk)  # fmt: skip


def scene_boxes(sc, objects: np.ndarray) -> SceneBoxes:
    """The boxes of scenario `sc` with its movable objects at poses `objects` (n, 7)."""
    boxes = [(b, True) for b in sc.movable] + [(b, False) for b in sc.fixed]
    fixed = [np.array([b.x, b.y, b.zc, *yaw_quat(b.yaw)]) for b in sc.fixed]
    centers, rots = [], []
    for _, pose in zip(boxes, [*np.asarray(objects, np.float64), *fixed], strict=True):
        m = np.zeros(9)
        mujoco.mju_quat2Mat(m, pose[3:])
        centers.append(pose[:3])
        rots.append(m.reshape(3, 3))
    return SceneBoxes(
        names=tuple(b.name for b, _ in boxes),
        movable=np.array([m for _, m in boxes], bool),
        centers=np.asarray(centers, np.float64).reshape(-1, 3),
        rots=np.asarray(rots, np.float64).reshape(-1, 3, 3),
        halves=np.asarray([b.half for b, _ in boxes], np.float64).reshape(-1, 3),
    )


def cut_at_fixed(
    fixed_clearance: np.ndarray | None,
    owner: np.ndarray,
    k: np.ndarray,
    lengths: np.ndarray,
    counted: np.ndarray | None = None,
) -> np.ndarray:
    """(n_edges,) how many states of each edge come before its first (counted) state within
    FIXED_MARGIN of a fixed obstacle (`fixed_clearance`, per state of the edges concatenated;
    None: no fixed obstacle), or all of them.  `owner`, `k`: each state's edge and index in
    it.  The one cut an action makes at the wall; callers drop what keeps fewer than
    MIN_EDGE_STATES states (`TransitPlanner.edge_prefixes`, `pushfield.push_pairs`)."""
    prefix = np.asarray(lengths).copy()
    if fixed_clearance is not None:
        near = fixed_clearance < FIXED_MARGIN
        if counted is not None:
            near &= counted
        np.minimum.at(prefix, owner[near], k[near])
    return prefix


def clearance_kernel(robot: Robot):
    """jit(vmap(arm_clearance)) over chunks of configurations (JAX, compiled once)."""
    from kernels.collision import arm_clearance
    from lmjx.runtime.batching import ChunkedKernel, backend

    unroll = backend() != "cpu"
    chunk = 1 << 16 if backend() != "cpu" else 256  # CPU: the planner's calls hold a few hundred configurations

    def one(q):
        return arm_clearance(robot.arm, q, unroll)

    return ChunkedKernel(("arm_clearance", robot.model_hash, unroll), one, [], [(np.float32, (robot.nq,))], chunk)


def box_slots(nb: int) -> int:
    """Boxes in the clearance program for a scene of `nb` boxes: EDGE_BOXES (the edges'
    program: the same compilation) where they fit, else MAX_BOXES.  Each box's clearance is
    computed apart, so a scene's figures do not depend on the program; a small scene (the
    tunnel, clutter) pays for 4 boxes instead of 16."""
    return EDGE_BOXES if nb <= EDGE_BOXES else MAX_BOXES


def box_kernel(robot: Robot, boxes: tuple[np.ndarray, np.ndarray, np.ndarray]):
    """jit(vmap(boxes_clearance)) over chunks of configurations, the scene's boxes shared
    (inputs: one program for every scene of as many boxes as `boxes` holds, padded; see
    `box_slots`)."""
    from kernels.collision import boxes_clearance
    from lmjx.runtime.batching import ChunkedKernel, backend

    unroll = backend() != "cpu"
    chunk = 1 << 14 if backend() != "cpu" else SMALL_CHUNK  # CPU: calls hold a few dozen configurations

    def one(centers, rots, halves, q):
        return boxes_clearance(robot.arm, q, centers, rots, halves, unroll)

    return ChunkedKernel(
        ("boxes_clearance", robot.model_hash, unroll, len(boxes[0])),
        one,
        list(boxes),
        [(np.float32, (robot.nq,))],
        chunk,
    )


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


class SceneChecks:
    """The checks of arm configurations and straight joint-space segments against the table, the
    arm itself and the scene set (`TransitPlanner.set_scene`): one configuration at a time with C
    MuJoCo, or batched with lmjx's clearance kernels (`batched`).  A part of `TransitPlanner`,
    which holds the state these read."""

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
            self._kernel = clearance_kernel(self.robot)
        out = self._kernel.run(np.asarray(qs, np.float32))
        return (out["self_clearance"] < 0) | (out["table_clearance"] < 0)

    def box_clearance(self, qs: np.ndarray) -> np.ndarray:
        """(n, nb) the arm's clearance at each configuration of qs (n, nj) to each box of the
        scene (lmjx's box-clearance kernel, on the accelerator JAX uses)."""
        assert self.scene is not None, "set_scene first"
        n = box_slots(len(self.scene.names))
        if n not in self._box_kernels:  # later scenes of n slots set theirs (`set_scene`)
            self._box_kernels[n] = box_kernel(self.robot, self.scene.padded(n))
        out = self._box_kernels[n].run(np.asarray(qs, np.float32))["box_clearance"]
        return out[:, : len(self.scene.names)]

    def lower_bounds(self, qs: np.ndarray) -> np.ndarray:
        """(n, nb) a lower bound of the arm's clearance to each box of the scene: each capsule
        axis's distance to the box's centre less the capsule's radius and the box's
        circumradius (lmjx's bound kernel, `kernels.collision.boxes_lower_bound`: a pass far
        cheaper than the exact clearance, which only the configurations this leaves in doubt
        need), less BOUND_SLACK (its float32 rounding)."""
        assert self.scene is not None
        n = box_slots(len(self.scene.names))
        if n not in self._bound_kernels:  # later scenes of n slots set theirs (`set_scene`)
            self._bound_kernels[n] = bound_kernel(self.robot, self.scene.bound_inputs(n))
        out = self._bound_kernels[n].run(np.asarray(qs, np.float32))["box_bound"]
        return out[:, : len(self.scene.names)].astype(np.float64) - BOUND_SLACK

    def scene_slacks(self, qs: np.ndarray) -> np.ndarray:
        """(n, nb) how far each configuration keeps outside each box's margin (its clearance
        less the margin: negative inside it; (n, 0) without a scene): the exact clearance
        wherever the lower bound leaves some box in doubt, else the bound's."""
        if self.scene is None or not len(self.scene.names) or not len(qs):
            return np.zeros((len(qs), 0 if self.scene is None else len(self.scene.names)))
        margins = self.scene.margins()
        if self._host_bounds:
            out = self.lower_bounds(qs) - margins
            doubt = np.any(out < 0, axis=1)
        else:
            out = np.zeros((len(qs), len(margins)))
            doubt = np.ones(len(qs), bool)
        if doubt.any():
            out[doubt] = self.box_clearance(np.asarray(qs)[doubt]) - margins
        return out + self._relax * self.scene.movable

    def scene_slack(self, qs: np.ndarray) -> np.ndarray:
        """(n,) the smallest of `scene_slacks` (+inf without a scene)."""
        s = self.scene_slacks(qs)
        return s.min(axis=1) if s.shape[1] else np.full(len(qs), np.inf)

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

    def scene_blocked(self, qs: np.ndarray) -> np.ndarray:
        """(n,) whether each configuration comes within the margins of an object or a fixed
        obstacle of the scene (all False without a scene)."""
        return self.scene_slack(qs) < 0

    def blocked(self, qs: np.ndarray) -> np.ndarray:
        """(n,) table, arm or scene in the way at each configuration."""
        return self.colliding_batch(qs) | self.scene_blocked(qs)

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
