"""The scene as the arm's checks see it: its boxes at their observed poses, the margins kept
from movable objects and fixed obstacles, and the checks of arm configurations against the
table, the arm itself and the boxes (C MuJoCo one at a time, or lmjx's clearance kernels
batched over many; a cheap lower bound first where the checks run on the host).  The
planner's transits (`lmjx.planner.clearance`, `lmjx.planner.transit`) and the map's push
counts (`lmjx.mapfile.pushmap`) check against it; nothing here plans.

An upright cylinder (`lmjx.sim.scenarios.Cylinder`) is checked exactly: the clearance
program of a scene with cylinders takes their signed distance (`kernels.collision.
cylinder_sdf`; `padded` marks a cylinder's row by a negative y half size), a program apart
made the first time a scene has one (`BoxKernel`), so that scenes of boxes alone run the
boxes' program as ever; the lower bound takes a cylinder's own circumradius.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from lmjx.model.robot import Robot
from lmjx.sim.scene import yaw_quat

OBJECT_MARGIN = 0.01  # a transit keeps this far from every movable object [m]
FIXED_MARGIN = 0.02  # ... and this far from every fixed obstacle [m]
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
    halves: np.ndarray  # (nb, 3) (a cylinder's: radius, radius, half height)
    cylinders: np.ndarray | None = None  # (nb,) bool: upright cylinders (None: none)

    def cylinder_mask(self) -> np.ndarray:
        """(nb,) which boxes are upright cylinders."""
        return np.zeros(len(self.names), bool) if self.cylinders is None else np.asarray(self.cylinders, bool)

    def margins(self) -> np.ndarray:
        return np.where(self.movable, OBJECT_MARGIN, FIXED_MARGIN)

    def padded(self, n: int = MAX_BOXES, which: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(centres, rotations, half sizes) of `n` boxes, float32: the scene's (or those
        `which` lists), then boxes of no size far below the table; a cylinder's row of half
        sizes is (radius, -radius, half height), the clearance program's mark of one."""
        which = np.arange(len(self.names)) if which is None else np.asarray(which)
        nb = len(which)
        if nb > n:
            raise ValueError(f"a scene of {nb} boxes: the clearance program holds {n}")
        c = np.zeros((n, 3), np.float32)
        c[nb:, 2] = -100.0
        r = np.tile(np.eye(3, dtype=np.float32), (n, 1, 1))
        h = np.zeros((n, 3), np.float32)
        c[:nb], r[:nb], h[:nb] = self.centers[which], self.rots[which], self.halves[which]
        h[:nb, 1] = np.where(self.cylinder_mask()[which], -h[:nb, 1], h[:nb, 1])
        return c, r, h

    def bound_inputs(self, n: int = MAX_BOXES) -> tuple[np.ndarray, np.ndarray]:
        """(centres, circumradii) of `n` box slots, float32, for the lower bound's program:
        the scene's boxes (a cylinder's: the hypotenuse of its radius and half height),
        then points far below the table."""
        c, _, h = self.padded(n)
        h[:, 1] = np.where(h[:, 1] < 0, 0.0, h[:, 1])  # (a cylinder: its radius once)
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
    """The boxes and cylinders of scenario `sc` with its movable objects at poses `objects`
    (n, 7)."""
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
        cylinders=np.array([b.shape == "cylinder" for b, _ in boxes], bool),
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
    MIN_EDGE_STATES states (`TransitPlanner.edge_prefixes`, `pushmap.push_pairs`)."""
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


def _box_program(robot: Robot, boxes: tuple[np.ndarray, ...], cylinders: bool):
    """jit(vmap(boxes_clearance)) over chunks of configurations, the scene's boxes shared:
    the boxes' program, or (`cylinders`) the one that also takes cylinders exactly."""
    from kernels.collision import boxes_clearance
    from lmjx.runtime.batching import ChunkedKernel, backend

    unroll = backend() != "cpu"
    chunk = 1 << 14 if backend() != "cpu" else SMALL_CHUNK  # CPU: calls hold a few dozen configurations

    def one(centers, rots, halves, q):
        return boxes_clearance(robot.arm, q, centers, rots, halves, unroll, cylinders)

    key = ("boxes_clearance", robot.model_hash, unroll, len(boxes[0])) + (("cylinders",) if cylinders else ())
    return ChunkedKernel(key, one, list(boxes), [(np.float32, (robot.nq,))], chunk)


class BoxKernel:
    """The arm's clearance to a scene's boxes over chunks of configurations (`run(q)` ->
    {"box_clearance": (n, slots)}), the boxes given by `set_shared(*SceneBoxes.padded(...))`:
    the boxes' program while the scene has none but boxes, the one that takes cylinders too
    (made the first time a scene has one) while it has cylinders; each made once and given
    each later scene's boxes."""

    def __init__(self, robot: Robot, boxes: tuple[np.ndarray, ...]) -> None:
        self.robot = robot
        self.programs: dict[bool, Any] = {}
        self.cylinders = False
        self.set_shared(*boxes)

    def set_shared(self, *boxes: np.ndarray) -> None:
        self.cylinders = bool((np.asarray(boxes[2])[:, 1] < 0).any())
        if self.cylinders in self.programs:
            self.programs[self.cylinders].set_shared(*boxes)
        else:
            self.programs[self.cylinders] = _box_program(self.robot, boxes, self.cylinders)

    def run(self, *arrays: np.ndarray, **kw: Any) -> dict[str, np.ndarray]:
        return self.programs[self.cylinders].run(*arrays, **kw)


def box_kernel(robot: Robot, boxes: tuple[np.ndarray, np.ndarray, np.ndarray]) -> BoxKernel:
    """jit(vmap(boxes_clearance)) over chunks of configurations, the scene's boxes shared
    (inputs: one program for every scene of as many boxes as `boxes` holds, padded; see
    `box_slots`; a scene with cylinders: the program that takes them, `BoxKernel`)."""
    return BoxKernel(robot, boxes)


class SceneClearance:
    """Checks of arm configurations against the table, the arm itself and a scene's boxes
    (`place`): one configuration at a time with C MuJoCo, or batched with lmjx's clearance
    kernels (`batched`; each scene size's program made once and given each scene's boxes)."""

    def __init__(self, robot: Robot, batched: bool = False) -> None:
        from lmjx.runtime.batching import backend

        self.robot = robot
        self.m = robot.mj
        self.d = mujoco.MjData(self.m)
        self.batched = batched
        self._kernel = None
        self._box_kernels: dict[int, Any] = {}  # box slots -> the scenes' clearance program (`box_slots`)
        self._bound_kernels: dict[int, Any] = {}  # box slots -> the scenes' lower-bound program
        self._host_bounds = backend() == "cpu"  # the cheap lower bound first (on the host)
        self._relax = 0.0  # movable objects' margins reduced by this much (a way out of a jam)
        self.scene: SceneBoxes | None = None

    def place(self, boxes: SceneBoxes) -> None:
        """Check against `boxes` from now on (the programs of their size given them)."""
        self.scene = boxes
        n = box_slots(len(boxes.names))
        if n in self._box_kernels:
            self._box_kernels[n].set_shared(*boxes.padded(n))
        if n in self._bound_kernels:
            self._bound_kernels[n].set_shared(*boxes.bound_inputs(n))

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

    def scene_blocked(self, qs: np.ndarray) -> np.ndarray:
        """(n,) whether each configuration comes within the margins of an object or a fixed
        obstacle of the scene (all False without a scene)."""
        return self.scene_slack(qs) < 0

    def blocked(self, qs: np.ndarray) -> np.ndarray:
        """(n,) table, arm or scene in the way at each configuration."""
        return self.colliding_batch(qs) | self.scene_blocked(qs)
