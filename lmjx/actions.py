"""Actions: the transit from the robot's current configuration to an edge's start, then the
edge itself, as joint targets at the control rate; and the servo controls a simulator
applies at its physics rate.

The transit is a straight line in joint space, timed so that no joint exceeds half its
velocity limit (a chain of lines slows to rest into each sharp corner and speeds up out of
it: `lmjx.timing`, applied to the whole transit once it is built); when that line would
take the arm into the table or into itself (checked with C MuJoCo at every control step, or
by lmjx's clearance kernel), or within
`OBJECT_MARGIN` of a movable object or `FIXED_MARGIN` of a fixed obstacle (the planner's
whole scene at its observed poses, `set_scene`; lmjx's box-clearance kernel, batched over
every configuration of every candidate), it retreats first: up to the failure's park pose
(the arm raised clear of the table), then straight down to the edge's start; where the
straight way up is blocked, by a dog-leg (some joints to their park values first, then the
rest; `to_park`), whose first leg may pass movable objects at `JAM_MARGIN` when nothing
keeps the full margin (the arm boxed in by objects a push has moved).  When that too is
blocked, the action is not offered.  An edge whose start lies within the margins of
an object is not offered either (with `late_start`, an option, an edge whose start lies in a
fixed obstacle's margin may be entered at its first clear state where the clear starts give
too few actions: `late_starts`).  An edge whose states come within `FIXED_MARGIN` of a fixed
obstacle is executed only up to its last state before that (`edge_prefixes`; an arm pushing
the target into the tunnel stops short of the wall instead of giving up the push), and not
offered when fewer than `MIN_EDGE_STATES` states are left; nor, once a scene is set, is an
edge that does not intersect the target within what is executed: whose arm never sweeps
`ACT_DEPTH` into the target's box (the spatial index's cells are a coarse first cut; this is
the exact test, capsules against the target's box at every executed state; an edge that
only grazes the observed box mostly misses the real one, 2 mm off).

After an edge the arm often stands inside the margins (it pushed something): the transits
of the next action then begin with a `retreat` back along that edge until the arm is clear
(`came_from`; or, where the way back crosses an object the push moved, only until it is out
of every margin); where there is none, a transit may leave the margins directly, never going
deeper on the way out, never entering another object's.  Where even that gives an edge no
transit (the arm wedged between objects the push moved behind it), the edge's transit begins
with an `escape`: a path of small joint steps, found by a beam search, none of which goes
deeper into any margin, until the arm is clear.  Nothing here chooses actions.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from .bundle import Bundle
from .failure import Failure
from .roadmap import Roadmap
from .robot import Robot
from .scene import yaw_quat
from .timing import retime

CONTROL_DT = 0.02  # the edges' control period [s]
OBJECT_MARGIN = 0.01  # a transit keeps this far from every movable object [m]
FIXED_MARGIN = 0.02  # ... and this far from every fixed obstacle [m]
JAM_MARGIN = 0.004  # the first leg of a way out of a jam (`to_park`) keeps this far from movable objects [m]
ACT_DEPTH = 0.005  # an edge acts on the target when the arm sweeps this deep into its box [m]
LEAVE_TOLERANCE = 0.0002  # a transit leaving a contact may come this much nearer than it began [m] (kernel noise)
RETREAT_SLACK = 0.005  # a retreat backs out until the arm keeps this far outside the scene's margins [m]
RETREAT_STEP = 0.05  # the retreat's waypoints: at least this far apart (largest joint motion) [rad]
NEAR_SPEED = 0.1  # inside the margins the arm moves at this fraction of the transits' speed
ESCAPE_STEP = 0.01  # the way out of a jam (`escape`): largest joint motion of one step [rad]
# `TransitPlanner.actions`' tally of the edges it tested and why those not offered were not:
# the start blocked (the table, the arm itself, or within an object's or obstacle's margins),
# the edge itself unusable (cut short at a fixed obstacle, or not acting on the target), or
# no transit to its start
NO_ACTION_KEYS = ("tested", "start_blocked", "edge_unusable", "no_transit")
ESCAPE_STEPS = 100  # ... at most this many steps (rounds of its search)
ESCAPE_DIRS = 64  # ... directions tried at each step besides the free joints' own
ESCAPE_SCALES = (1.0, 0.5, 0.25)  # ... each at these fractions of ESCAPE_STEP
ESCAPE_BEAM = 32  # ... the search's paths kept each round
MEMO_KEYS = 4  # per-decision caches (`_memo`): the latest this many keys
TRAIL_NODES = 1024  # the way back (`trail_back`): at most this many nodes, RETREAT_STEP apart (to the park pose)
MAX_BOXES = 16  # boxes of a scene in one clearance program (padded)
MIN_BLOCK = 32  # edges tested at a time when looking for feasible actions
EDGE_BOXES = 4  # the target and up to three fixed obstacles, in the program testing edges' states
MIN_EDGE_STATES = 5  # an edge cut short at a fixed obstacle keeps at least this many states (0.1 s)
LATE_TRIES = 4  # `late_start`: edges with a blocked start tried per action still wanted
SMALL_CHUNK = 64  # configurations per call of the planner's clearance programs on the CPU
# (a call holds a median of about 40: a chunk of 256 cost 5.3 ms for 40 where 64 costs 1.1 ms)
OPTIONS_SAMPLE = 256  # `options`: edges whose starts it tests
OPTIONS_CHECK = 64  # `options`: clear ones whose states it tests
WHOLE = np.iinfo(np.int32).max  # `edge_prefixes` of an edge executed whole (no scene)


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


@dataclass
class Action:
    """A planned action: joint targets q* and velocities qd* at the control rate."""

    edge: int  # edge id in the bundle
    q: np.ndarray  # (T, nq)
    qd: np.ndarray  # (T, nq)
    transit_steps: int  # the first transit_steps rows move to the edge's start
    via_park: bool  # the transit is not the straight line (through the park pose, or the roadmap)
    route: str = "direct"  # the transit: "direct", "park" (through the park pose), "roadmap"; "escape+" any of them
    edge_states: int = -1  # the edge's states executed (fewer than its own where a fixed obstacle cuts it short)
    edge_first: int = 0  # the edge's first state executed (`late_start`: its start in a fixed obstacle's margin)

    @property
    def duration(self) -> float:
        return len(self.q) * CONTROL_DT


def after_executing(action: Action, trail: np.ndarray, dtype) -> tuple[np.ndarray, np.ndarray]:
    """What a trial keeps of an action it executed, for the transits that follow: the edge's
    states executed (`came_from`, in the map's precision `dtype`: a whole edge as it is
    stored), and `trail` extended by every joint target the arm followed."""
    return action.q[action.transit_steps :].astype(dtype), np.concatenate([trail, action.q])


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


class TransitPlanner:
    """Builds collision-free joint-space transits for one failure.

    Collisions are checked one configuration at a time with C MuJoCo, or, with `batched`,
    every configuration of many candidate transits at once with lmjx's clearance kernel
    (`kernels.collision.arm_clearance`, on the accelerator JAX uses): the same checks
    (tests/test_planning.py compares the two), for planners that build thousands of
    actions per decision.  Transits through the park pose are remembered per edge: the
    park-to-start half does not depend on where the arm is.
    """

    def __init__(
        self, robot: Robot, failure: Failure, speed_fraction: float = 0.5, batched: bool = False, search: bool = True
    ) -> None:
        self.robot = robot
        self.failure = failure
        self.m = robot.mj
        self.d = mujoco.MjData(self.m)
        self.speed = speed_fraction * robot.qd_max
        self.park = park_pose(robot, failure)
        self.batched = batched
        self._kernel = None
        self._box_kernels: dict[int, Any] = {}  # box slots -> the scenes' clearance program (`box_slots`)
        self._edge_kernel = None
        from .batching import backend

        self._host_bounds = backend() == "cpu"  # the cheap lower bound first (on the host)
        self._scene_version: Any = 0  # the scene set, by content (`set_scene`): the caches' keys hold it
        self._forgotten = 0  # how often `forget` was called (part of every scene version since)
        self._relax = 0.0  # movable objects' margins reduced by this much (`to_park`'s way out of a jam)
        self._to_park: dict = {}  # (where from, in which scene) -> the transit to the park pose (`_memo`)
        self._retreat: dict = {}  # (where from, along what, in which scene) -> (the retreat, jammed) (`_memo`)
        self._escape: dict = {}  # (where from, in which scene) -> the `escape` (`_memo`)
        self.last_tally: dict[str, int] = {}  # the last `actions` call's edges, by why they were not offered
        self._trail: dict = {}  # (where from, how long a trail, in which scene) -> `trail_back` (`_memo`)
        self.scene: SceneBoxes | None = None
        # offer only edges that bring the arm into contact range of the target (set_scene)
        self.acting = False
        self._from_park: dict[tuple, np.ndarray | None] = {}  # (bundle id, edge, start) -> park -> start
        self.search = search  # where the straight transit and the park's are blocked, search a roadmap
        # where the edges with clear starts give fewer actions than wanted, edges whose start lies
        # within FIXED_MARGIN of a fixed obstacle are entered at their first state clear of
        # everything (`late_starts`; at most LATE_TRIES of them per action still wanted)
        self.late_start = False
        self._roadmaps: dict[int, Roadmap] = {}  # bundle id -> its roadmap

    def set_scene(self, sc, objects: np.ndarray, acting: bool = True) -> None:
        """The scene transits must keep clear of from now on: scenario `sc` with its movable
        objects observed at `objects` (n, 7), the target first.  `acting`: offer only edges
        that sweep ACT_DEPTH into the target's box.

        Trials run together (`lmjx.lockstep`) share one TransitPlanner and each sets its own
        scene before it asks for actions, again after every simulation it waited for (another
        trial may have set its scene meanwhile).  Setting the scene that is already set
        changes nothing; a scene's version is its content's, so what was kept for a trial's
        scene (`_memo`) serves it again when it comes back to it."""
        objects = np.asarray(objects, np.float64)
        # the scene's content (Scenario is frozen), in this planner's memory since its last `forget`
        key = (self._forgotten, sc, objects.shape, objects.tobytes(), bool(acting))
        if self.scene is not None and key == self._scene_version:
            return
        self.scene = scene_boxes(sc, objects)
        self._scene_version = key
        self.acting = acting
        self._from_park.clear()  # park -> start depends on where the objects are
        n = box_slots(len(self.scene.names))
        if n in self._box_kernels:
            self._box_kernels[n].set_shared(*self.scene.padded(n))

    def forget(self) -> None:
        """Drop what was kept about the scenes set so far (the transits through the park pose,
        the ways out of a jam, the roadmaps' free nodes and links): the next `set_scene`
        starts afresh even for a scene already seen: every scene version from now on differs
        from those before, so nothing cached under one (`_memo`, the roadmaps) is found again."""
        for slot in ("_to_park", "_retreat", "_escape", "_trail"):
            getattr(self, slot).clear()
        self._forgotten += 1
        self._scene_version = 0

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

    def box_clearance(self, qs: np.ndarray) -> np.ndarray:
        """(n, nb) the arm's clearance at each configuration of qs (n, nj) to each box of the
        scene (lmjx's box-clearance kernel, on the accelerator JAX uses)."""
        assert self.scene is not None, "set_scene first"
        n = box_slots(len(self.scene.names))
        if n not in self._box_kernels:  # later scenes of n slots set theirs (`set_scene`)
            self._box_kernels[n] = _box_kernel(self.robot, self.scene.padded(n))
        out = self._box_kernels[n].run(np.asarray(qs, np.float32))["box_clearance"]
        return out[:, : len(self.scene.names)]

    def lower_bounds(self, qs: np.ndarray) -> np.ndarray:
        """(n, nb) a lower bound of the arm's clearance to each box of the scene: each capsule
        axis's distance to the box's centre less the capsule's radius and the box's
        circumradius (the capsules from lmjx's capsule kernel, a pass far cheaper than the
        exact clearance, which only the configurations this leaves in doubt need)."""
        from .bundle import capsule_ends_kernel

        assert self.scene is not None
        # (on the host: the CPU backend's bound, `_host_bounds`, in calls of a few dozen)
        ends = capsule_ends_kernel(self.robot, SMALL_CHUNK).run(np.asarray(qs, np.float32))
        a, b = ends["a"].astype(np.float64), ends["b"].astype(np.float64)  # (n, nc, 3)
        c = self.scene.centers  # (nb, 3)
        d = b - a
        ap = c[None, None] - a[:, :, None]  # (n, nc, nb, 3)
        t = np.clip(np.einsum("ncbk,nck->ncb", ap, d) / np.maximum(np.einsum("nck,nck->nc", d, d), 1e-12)[..., None],
                    0.0, 1.0)  # fmt: skip
        gap = np.linalg.norm(ap - t[..., None] * d[:, :, None], axis=-1)  # (n, nc, nb)
        radius = np.asarray(self.robot.arm.cap_r)[None, :, None]
        return (gap - radius).min(axis=1) - np.linalg.norm(self.scene.halves, axis=1)[None]

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

    def _timing(self, dq: np.ndarray, slow: np.ndarray | bool = False) -> tuple[np.ndarray, np.ndarray]:
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
        n, fine = self._timing(dq, (start_slack.min(axis=1, initial=np.inf) < 0) | (self._relax > 0))
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

    def edges_usable(self, bundle: Bundle, edges: np.ndarray) -> np.ndarray:
        """(len(edges),) whether each edge has a usable part (`edge_prefixes` > 0)."""
        return self.edge_prefixes(bundle, edges) > 0

    def edge_prefixes(self, bundle: Bundle, edges: np.ndarray, first_state: np.ndarray | None = None) -> np.ndarray:
        """(len(edges),) how many of each edge's states an action executes: the states before
        the first that comes within FIXED_MARGIN of one of the scene's fixed obstacles (the
        real arm lags its targets: it may end nearer than planned, and its next transit starts
        there), or all of them; 0 (the edge is not offered) when that part has fewer than
        MIN_EDGE_STATES states or, with `acting`, never sweeps the arm ACT_DEPTH into the
        target's box (the scene's first box).  Without a scene every edge is whole
        (`WHOLE`).  `first_state` (per edge): the edge is executed from that state on, and only
        those states count (the prefix is still counted from the edge's own start)."""
        if self.scene is None or not len(edges):
            return np.full(len(edges), WHOLE)
        fixed = ~self.scene.movable
        if not (self.acting or fixed.any()):
            return np.full(len(edges), WHOLE)
        qs = [bundle.edge(int(e), ("q",))["q"] for e in edges]
        q_all = np.concatenate(qs).astype(np.float32)
        # the target and the fixed obstacles only (a program of EDGE_BOXES boxes), exactly
        # where the lower bound leaves it in doubt (near the target, near a fixed obstacle)
        keep = np.concatenate([[0], np.nonzero(fixed)[0]])
        # (an accelerator computes the exact clearance of everything faster than the host its bound)
        c = self.lower_bounds(q_all) if self._host_bounds else np.full((len(q_all), len(fixed)), -np.inf)
        doubt = (c[:, 0] <= -ACT_DEPTH) | np.any(c[:, fixed] < FIXED_MARGIN, axis=1)
        if doubt.any():
            if self._edge_kernel is None:
                self._edge_kernel = _box_kernel(self.robot, self.scene.padded(EDGE_BOXES, keep))
            else:
                self._edge_kernel.set_shared(*self.scene.padded(EDGE_BOXES, keep))
            exact = self._edge_kernel.run(q_all[doubt])["box_clearance"][:, : len(keep)]
            rows = np.nonzero(doubt)[0]
            c[np.ix_(rows, keep)] = exact
        lengths = np.array([len(q) for q in qs])
        first = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        owner = np.repeat(np.arange(len(qs)), lengths)
        k = np.arange(len(owner)) - first[owner]  # each state's index within its edge
        begin = np.zeros(len(qs), int) if first_state is None else np.asarray(first_state, int)
        counted = k >= begin[owner]
        prefix = cut_at_fixed(c[:, fixed].min(axis=1) if fixed.any() else None, owner, k, lengths, counted)
        if self.acting:
            inside = counted & (k < prefix[owner])
            nearest = np.full(len(qs), np.inf)
            np.minimum.at(nearest, owner[inside], c[inside, 0])
            prefix[nearest > -ACT_DEPTH] = 0
        prefix[prefix - begin < MIN_EDGE_STATES] = 0
        return prefix

    def late_starts(self, bundle: Bundle, edges: np.ndarray) -> np.ndarray:
        """(len(edges),) for edges whose start is blocked: the first state of each that the arm
        could be at (not blocked: clear of the table, the arm itself and every margin of the
        scene) after a start within FIXED_MARGIN of a fixed obstacle; -1 where the start is
        not within a fixed obstacle's margin (blocked by a movable object, the table or the
        arm: such an edge is not entered late) or no later state is clear."""
        out = np.full(len(edges), -1)
        if self.scene is None or not len(edges) or self.scene.movable.all():
            return out
        starts = bundle.q_start[edges].astype(np.float64)
        fixed = ~self.scene.movable
        slack = self.scene_slacks(starts)
        by_fixed = slack[:, fixed].min(axis=1) < 0
        if not by_fixed.any():
            return out
        which = np.nonzero(by_fixed)[0]
        qs = [bundle.edge(int(edges[i]), ("q",))["q"].astype(np.float64) for i in which]
        q_all = np.concatenate(qs)
        free = ~self.blocked(q_all)
        lengths = np.array([len(q) for q in qs])
        ends = np.cumsum(lengths)
        for i, a, b in zip(which, ends - lengths, ends, strict=True):
            hits = np.nonzero(free[a:b])[0]
            if len(hits):
                out[i] = int(hits[0])
        return out

    def options(
        self,
        bundle: Bundle,
        edges: np.ndarray,
        rng: np.random.Generator,
        sample: int = OPTIONS_SAMPLE,
        check: int = OPTIONS_CHECK,
    ) -> float:
        """An estimate of how many of `edges` (those over the target) this scene would offer,
        transits aside: their share whose start is clear (`blocked`) in a sample of `sample`,
        times the share usable (`edge_prefixes` > 0: acting on the target, not cut short at a
        fixed obstacle) of at most `check` of those, times len(edges)."""
        edges = np.asarray(edges)
        if not len(edges):
            return 0.0
        part = np.sort(edges if len(edges) <= sample else rng.choice(edges, sample, replace=False))
        free = ~self.blocked(bundle.q_start[part].astype(np.float64))
        if not free.any():
            return 0.0
        clear = part[free]
        clear = np.sort(clear if len(clear) <= check else rng.choice(clear, check, replace=False))
        usable = float((self.edge_prefixes(bundle, clear) > 0).mean())
        return len(edges) * float(free.mean()) * usable

    def action(self, bundle: Bundle, edge: int, q_now: np.ndarray) -> Action | None:
        acts = self.actions(bundle, np.array([edge]), q_now, 1)
        return acts[0] if acts else None

    def retreat(self, q_now: np.ndarray, came_from: np.ndarray) -> np.ndarray | None:
        """Joint targets (T, nq) backing the arm out of the scene's margins the way it came:
        along `came_from` (the states of the edge it just executed) in reverse, from the state
        nearest `q_now` back to the first that keeps RETREAT_SLACK outside every margin or,
        when the way there is blocked, back to the first outside every margin; or None if
        neither exists, or the way back comes nearer to anything than the arm is now
        (LEAVE_TOLERANCE), or enters the table or the arm itself.

        An edge that pushed an object ends against it, inside the margins a transit keeps;
        a transit leaving sideways keeps within millimetres of it, which the real arm (its
        tracking error, the observation's noise) turns into contacts.  Backing out along the
        edge moves straight away from whatever the edge approached.  The way all the way back
        may cross where the push left another object (an edge is checked against the target
        and the fixed obstacles only): then the arm backs out just far enough to be clear of
        every margin, and the transit goes on from there."""
        path = np.asarray(came_from, np.float64)
        j = int(np.argmin(np.abs(path - q_now).max(axis=1)))  # where along its way the arm stands
        back = path[max(j - 1, 0) :: -1]
        slack = self.scene_slack(back)
        tried: set[int] = set()
        for need in (RETREAT_SLACK, 0.0):
            clear = np.nonzero(slack >= need)[0]
            if not len(clear) or int(clear[0]) in tried:
                continue
            tried.add(int(clear[0]))
            way = self._back_along(q_now, back[: clear[0] + 1])
            if way is not None:
                return way
        return None

    def _back_along(self, q_now: np.ndarray, back: np.ndarray, every: bool = False) -> np.ndarray | None:
        """Joint targets from q_now through the states `back` (waypoints RETREAT_STEP apart,
        the last kept; `every`: all of them) at NEAR_SPEED, or None where `_leaves_cleanly` or
        the table and the arm forbid it."""
        way = np.asarray([q_now, *(back[:-1] if every else _spaced(q_now, back[:-1])), back[-1]])
        dq = np.diff(way, axis=0)
        n, fine = self._timing(dq, True)
        checks = np.concatenate([way[i] + np.outer(np.arange(1, f + 1) / f, dq[i]) for i, f in enumerate(fine)])
        both = np.concatenate([q_now[None], checks])
        slack = self.scene_slacks(both)
        hits = self.colliding_batch(both)
        free_before = np.logical_or.accumulate(~hits[:-1])
        if hits[-1] or np.any(hits[1:] & free_before) or not self._leaves_cleanly(slack[0], slack[1:]):
            return None
        return np.concatenate([way[i] + np.outer(np.arange(1, k + 1) / k, dq[i]) for i, k in enumerate(n)])

    def escape(self, q_now: np.ndarray) -> np.ndarray | None:
        """Joint targets (T, nq) taking the arm out of the scene's margins when it stands
        inside them and neither the way back (`retreat`) nor a transit from where it stands
        exists (a push left it wedged between objects that moved behind it).

        A beam search over small joint steps (free joints only, within the joint limits): the
        escape's directions (`escape_directions`) at ESCAPE_SCALES of ESCAPE_STEP (largest
        joint motion).  A step is allowed when, at every check `_back_along` will make along
        it (the same fractions), the arm goes no deeper (LEAVE_TOLERANCE) into any margin than
        it began and enters no other nor one it has left on its way, the movable objects'
        margins reduced to JAM_MARGIN as on `to_park`'s way out of a jam; and it touches
        neither the table nor the arm itself.  Each round expands the ESCAPE_BEAM best paths
        (by the smallest slack their last state leaves to any box's full margin) by every
        allowed step to a state not reached before (a grid of a quarter step), for at most
        ESCAPE_STEPS rounds, until a path keeps RETREAT_SLACK outside every full margin;
        failing that (the arm wedged in a gap), the first path found outside them all.  A
        greedy walk (a beam of one) dead-ends in a wedge where every step from its second
        state goes deeper into something (trial 1005 of the hard set); the beam keeps other
        ways open.  The path, all its steps, is then checked like a retreat (`_back_along`,
        with the same margins: at NEAR_SPEED; the table and the arm itself).  None if no step
        is allowed or no path gets the arm out."""
        if self.scene is None:
            return None
        q0 = np.asarray(q_now, np.float64)
        base = self.escape_directions(len(q0))
        dirs = np.concatenate([s * ESCAPE_STEP * base for s in ESCAPE_SCALES])
        relax = (OBJECT_MARGIN - JAM_MARGIN) * self.scene.movable  # (nb,) added to the full margins' slacks
        slack0 = self.scene_slacks(q0[None])[0]
        start = slack0 + relax  # against the reduced margins: how deep the arm began in each
        cell = 0.25 * ESCAPE_STEP * min(ESCAPE_SCALES)

        def key(q: np.ndarray) -> bytes:
            return np.round(q / cell).astype(np.int64).tobytes()

        def keeps(was: np.ndarray, slacks: np.ndarray) -> np.ndarray:  # the rule, (n,) of (n, nb) reduced slacks
            return np.all(np.where(was, slacks >= 0, slacks >= start - LEAVE_TOLERANCE), axis=1)

        # the beam: (state, its full-margin slacks, boxes whose reduced margin the path has
        # been outside: never again inside, the path's states)
        beam = [(q0, slack0, start >= 0, [])]
        seen = {key(q0)}
        first_out = None  # the first path found outside every full margin
        for _ in range(ESCAPE_STEPS):
            if beam[0][1].min() >= RETREAT_SLACK:
                break
            q = np.stack([b[0] for b in beam])
            qs = np.clip(q[:, None] + dirs[None], self.robot.lower, self.robot.upper).reshape(-1, len(q0))
            owner = np.repeat(np.arange(len(beam)), len(dirs))
            new = np.array([key(x) not in seen for x in qs])
            # the steps' ends first (cheap): a step whose end is refused is refused
            end = self.scene_slacks(qs[new]) + relax
            was = np.stack([b[2] for b in beam])[owner[new]]
            ok = keeps(was, end)
            qs, owner = qs[new][ok], owner[new][ok]
            if not len(qs):
                break
            dq = qs - q[owner]
            _, fine = self._timing(dq, True)  # `_back_along`'s checks along each step
            most = int(fine.max())
            frac = np.minimum(np.arange(1, most + 1)[None] / fine[:, None], 1.0)  # (n, most); 1 repeats the end
            checks = q[owner][:, None] + frac[..., None] * dq[:, None]  # (n, most, nq)
            then = np.empty((len(qs), most, len(start)))
            then[:, -1] = end[ok]
            if most > 1:
                then[:, :-1] = (
                    self.scene_slacks(checks[:, :-1].reshape(-1, len(q0))).reshape(len(qs), most - 1, -1) + relax
                )
            was = was[ok]
            allowed = np.ones(len(qs), bool)
            for k in range(most):
                allowed &= keeps(was, then[:, k])
                was = was | (then[:, k] >= 0)
            after = then[:, -1] - relax
            kept = np.minimum(after, RETREAT_SLACK)
            score = kept.min(axis=1) + 1e-3 * kept.sum(axis=1)
            order = list(np.nonzero(allowed)[0][np.argsort(-score[allowed], kind="stable")])
            nxt = []
            while order and len(nxt) < ESCAPE_BEAM:  # the best first; the table and the arm checked as needed
                part = [i for i in order[: 2 * ESCAPE_BEAM] if key(qs[i]) not in seen]
                order = order[2 * ESCAPE_BEAM :]
                if not part:
                    continue
                hits = self.colliding_batch(checks[part].reshape(-1, len(q0))).reshape(len(part), most).any(axis=1)
                for i in np.asarray(part)[~hits]:
                    if len(nxt) == ESCAPE_BEAM or key(qs[i]) in seen:
                        continue
                    seen.add(key(qs[i]))
                    nxt.append((qs[i], after[i], was[i], [*beam[owner[i]][3], qs[i]]))
                    if first_out is None and after[i].min() >= 0:
                        first_out = nxt[-1][3]
            if not nxt:
                break
            beam = nxt
        way = beam[0][3] if beam[0][1].min() >= RETREAT_SLACK else first_out
        if not way:
            return None
        self._relax = OBJECT_MARGIN - JAM_MARGIN
        try:
            return self._back_along(q0, np.asarray(way), every=True)
        finally:
            self._relax = 0.0

    def escape_directions(self, nq: int) -> np.ndarray:
        """The escape's directions (n, nq), each scaled to a largest joint motion of 1: each free
        joint either way, then ESCAPE_DIRS seeded mixtures of the free joints."""
        free = np.asarray(self.failure.free(nq))
        axes = np.zeros((2 * len(free), nq))
        axes[np.arange(len(free)), free] = 1.0
        axes[len(free) + np.arange(len(free)), free] = -1.0
        mix = np.zeros((ESCAPE_DIRS, nq))
        mix[:, free] = np.random.default_rng(0).uniform(-1.0, 1.0, (ESCAPE_DIRS, len(free)))
        return np.concatenate([axes, mix / np.abs(mix).max(axis=1, keepdims=True)])

    def trail_back(self, source: np.ndarray, trail: np.ndarray) -> np.ndarray:
        """The way the arm came, back from `source`, as roadmap nodes (k, nj): the states of
        `trail` (every joint target the arm followed, oldest first) from the latest one
        nearest `source` backwards, RETREAT_STEP apart (largest joint motion), at most
        TRAIL_NODES of them, those now blocked (the table, the arm, the scene's margins)
        left out.  Where the arm was, it could move; the objects a push moved are checked
        again on every link (`Roadmap.transits`)."""
        trail = np.asarray(trail, np.float64)
        if not len(trail):
            return np.zeros((0, len(source)))
        gap = np.abs(trail - source).max(axis=1)
        j = int(np.nonzero(gap <= gap.min() + 1e-9)[0][-1])
        nodes = _spaced(source, trail[j::-1], TRAIL_NODES)
        if not nodes:
            return np.zeros((0, len(source)))
        nodes = np.asarray(nodes)
        return nodes[~self.blocked(nodes)]

    def actions(
        self,
        bundle: Bundle,
        edges: np.ndarray,
        q_now: np.ndarray,
        want: int,
        came_from: np.ndarray | None = None,
        trail: np.ndarray | None = None,
    ) -> list[Action]:
        """The first `want` feasible actions among `edges`, in their order (fewer if there are
        not that many).  Edges are taken in blocks (whatever the block, the same first
        actions): their starts first (one configuration each), then the edges' own tests
        (one batch of their states), then the transits of those that pass.

        `came_from`: the states of the edge the arm just executed.  Where the arm stands
        inside the scene's margins (it pushed something), every transit begins with the
        `retreat` along it; without one (none given, or none clear) a transit may leave the
        margins directly, never going deeper.  `trail`: every joint target the arm followed
        so far (oldest first); the roadmap may take the way back along it (`trail_back`).
        Where the arm stands inside the margins with no retreat, an edge with no transit from
        there is offered after the `escape` ("escape+" routes), in its place in the order.
        With `late_start`, where all of `edges` give fewer than `want` actions, a second pass
        enters edges whose start was blocked at their `late_starts` (at most LATE_TRIES of
        them, in order, per action still wanted); their actions come after the others."""
        out: list[Action] = []
        tally = dict.fromkeys(NO_ACTION_KEYS, 0)  # why edges were not offered (`last_tally`)
        self.last_tally = tally
        q_arm, lead = q_now, np.zeros((0, len(q_now)))  # where the arm is; what it does first
        jammed = False  # inside the margins with no way back: transits may begin with the `escape`
        if came_from is not None and self.scene is not None:

            def way_back() -> tuple[np.ndarray | None, bool]:  # the retreat, and whether the arm is jammed
                inside = bool(self.scene_slack(q_now[None])[0] < 0)
                back = self.retreat(q_now, came_from) if inside else None
                return back, inside and back is None

            key = (q_now.tobytes(), np.asarray(came_from).tobytes(), self._scene_version)
            back, jammed = self._memo("_retreat", key, way_back)
            if back is not None:
                lead, q_now = back, back[-1]  # transits are planned from the retreat's end
        block = max(want, MIN_BLOCK)
        blocked_starts: list[np.ndarray] = []  # for `late_start`'s second pass
        for late in (False, True):
            if late and not (self.late_start and len(out) < want and blocked_starts):
                break
            # (at most LATE_TRIES per action wanted: a late start costs a test of every state of the edge)
            pool = np.concatenate(blocked_starts)[: LATE_TRIES * (want - len(out))] if late else edges
            i = 0
            while len(out) < want and i < len(pool):
                part = np.asarray(pool[i : i + block])
                i += len(part)
                if not late:
                    tally["tested"] += len(part)
                    # the cheapest test first: most edges over a target start where an object stands
                    free = ~self.blocked(bundle.q_start[part].astype(np.float64))
                    tally["start_blocked"] += int(len(part) - free.sum())
                    if self.late_start:
                        blocked_starts.append(part[~free])
                    begin = np.zeros(len(part), int)
                else:  # too few actions from clear starts: edges entered after a start in a fixed obstacle's margin
                    begin = self.late_starts(bundle, part)
                    free = begin > 0
                    tally["start_blocked"] -= int(free.sum())
                part, begin = part[free], begin[free]
                prefix = self.edge_prefixes(bundle, part, begin) if len(part) else np.zeros(0, int)
                tally["edge_unusable"] += int((prefix <= 0).sum())
                part, prefix, begin = part[prefix > 0], prefix[prefix > 0], begin[prefix > 0]
                if not len(part):
                    continue
                starts = bundle.q_start[part].astype(np.float64)
                for j in np.nonzero(begin)[0]:
                    starts[j] = bundle.edge(int(part[j]), ("q",))["q"][begin[j]]
                ways = self._ways(bundle, part, starts, list(range(len(part))), q_now, lead, trail)
                stuck = [j for j in range(len(part)) if j not in ways]
                if jammed and stuck:  # no way from where the arm stands: the same ways from the escape's end
                    esc = self._memo("_escape", (q_now.tobytes(), self._scene_version), lambda: self.escape(q_now))
                    if esc is not None:
                        for j, (route, transit) in self._ways(bundle, part, starts, stuck, esc[-1], esc, trail).items():
                            ways[j] = ("escape+" + route, transit)
                ok = sorted(ways)
                tally["no_transit"] += len(part) - len(ok)
                bundle.prefetch(part[ok][: want - len(out)], ("q", "qd"))  # a lazily read map: at once
                for j in ok:
                    route, transit = ways[j]
                    out.append(_action(bundle, int(part[j]), q_arm, transit, route, int(prefix[j]), int(begin[j])))
                    if len(out) == want:
                        break
                block = max(MIN_BLOCK, 2 * (want - len(out)))
        return out

    def _ways(
        self,
        bundle: Bundle,
        part: np.ndarray,
        starts: np.ndarray,
        idx: list[int],
        q_from: np.ndarray,
        lead: np.ndarray,
        trail: np.ndarray | None,
    ) -> dict[int, tuple[str, np.ndarray]]:
        """Transits from q_from to the starts of part[idx] (`starts`: those of all of part),
        each after `lead` (what the arm does first): j -> (route, joint targets), straight
        where it can, else through the park pose, else along the roadmap; none for j where
        all three are blocked."""
        direct = self.segments(np.repeat(q_from[None], len(idx), axis=0), starts[idx])
        out = {j: ("direct", np.concatenate([lead, d])) for j, d in zip(idx, direct, strict=True) if d is not None}
        rest = [j for j in idx if j not in out]
        for j, t in self._via_park(bundle, part, starts, q_from, rest).items():
            out[j] = ("park", np.concatenate([lead, t]))
        rest = [j for j in rest if j not in out]
        if rest and self.search:
            back = None if trail is None else self._trail_back(q_from, trail)
            found = self.roadmap(bundle).transits(q_from, starts[rest], back)
            for j, f in zip(rest, found, strict=True):
                if f is not None:
                    out[j] = ("roadmap", np.concatenate([lead, f]))
        return out

    def _trail_back(self, q_now: np.ndarray, trail: np.ndarray) -> np.ndarray:
        """`trail_back`, once per decision (Lazy asks one edge at a time)."""
        key = (q_now.tobytes(), len(trail), self._scene_version)
        return self._memo("_trail", key, lambda: self.trail_back(q_now, trail))

    def _memo(self, slot: str, key: tuple, make: Callable[[], Any]) -> Any:
        """What `make()` returns, kept in the dict attribute `slot` under `key` (one decision
        asks again and again: Lazy, one edge at a time; a jammed arm asks from where it stands
        and from the escape's end): the MEMO_KEYS latest keys."""
        held = getattr(self, slot)
        if key not in held:
            if len(held) >= MEMO_KEYS:
                del held[next(iter(held))]
            held[key] = make()
        return held[key]

    def roadmap(self, bundle: Bundle) -> Roadmap:
        """The roadmap over `bundle`'s edge starts (built on first use, kept per bundle)."""
        key = id(bundle)
        if key not in self._roadmaps:
            self._roadmaps[key] = Roadmap(self, bundle.q_start)
        return self._roadmaps[key]

    def to_park(self, q_now: np.ndarray) -> np.ndarray | None:
        """Joint targets from q_now to the park pose: the straight line, or where it is
        blocked (the arm among objects a push has moved) a dog-leg: first the joints of one
        subset to their park values, the others held (lifting the shoulder clear, say), then
        the rest; subsets of fewer joints first, all checked in one batch.  None if none is
        free."""
        first = self.segment(q_now, self.park)
        if first is not None:
            return first
        moving = [int(i) for i in np.nonzero(np.abs(self.park - q_now) > 1e-6)[0]]
        subsets = [c for k in range(1, len(moving)) for c in itertools.combinations(moving, k)]
        if not subsets:
            return None
        mids = np.repeat(q_now[None], len(subsets), axis=0)
        for row, c in zip(mids, subsets, strict=True):
            row[list(c)] = self.park[list(c)]
        for relax in (0.0, OBJECT_MARGIN - JAM_MARGIN):
            # the first leg, at NEAR_SPEED when it starts inside the margins, may pass the
            # movable objects at JAM_MARGIN where no leg keeps OBJECT_MARGIN (a push left the
            # arm boxed in); the second leg, and everything after, keeps the full margins
            self._relax = relax
            try:
                legs_a = self.segments(np.repeat(q_now[None], len(mids), axis=0), mids)
            finally:
                self._relax = 0.0
            ok = [i for i, leg in enumerate(legs_a) if leg is not None]
            if not ok:
                continue
            legs_b = self.segments(mids[ok], np.repeat(self.park[None], len(ok), axis=0))
            for i, leg in zip(ok, legs_b, strict=True):
                if leg is not None:
                    return np.concatenate([legs_a[i], leg])
        return None

    def _via_park(
        self, bundle: Bundle, part: np.ndarray, starts: np.ndarray, q_now: np.ndarray, idx: list[int]
    ) -> dict[int, np.ndarray]:
        """Transits through the park pose for part[idx]: q_now -> park, then park -> start
        (`starts`: those of all of part; an edge entered late has its own)."""
        if not idx:
            return {}
        first = self._memo("_to_park", (q_now.tobytes(), self._scene_version), lambda: self.to_park(q_now))
        if first is None:
            return {}
        keys = {j: (id(bundle), int(part[j]), starts[j].tobytes()) for j in idx}
        todo = [j for j in idx if keys[j] not in self._from_park]
        if todo:
            park = np.repeat(self.park[None], len(todo), axis=0)
            for j, seg in zip(todo, self.segments(park, starts[todo]), strict=True):
                self._from_park[keys[j]] = seg
        out = {}
        for j in idx:
            second = self._from_park[keys[j]]
            if second is not None:
                out[j] = np.concatenate([first, second])
        return out


def _spaced(start: np.ndarray, states: np.ndarray, most: int | None = None) -> list[np.ndarray]:
    """The states of a path (in order) that lie RETREAT_STEP or more (largest joint motion)
    from the one kept before them, `start` first (not returned); at most `most` of them."""
    kept: list[np.ndarray] = []
    last = start
    for q in states:
        if np.abs(q - last).max() >= RETREAT_STEP:
            kept.append(q)
            last = q
            if len(kept) == most:
                break
    return kept


def transit_velocities(q_from: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """The joint velocities (T, nj) the servos are given with joint targets (T, nj) that lead
    on from q_from at CONTROL_DT: differences of q_from then targets (central; the last
    one-sided)."""
    return np.gradient(np.concatenate([np.asarray(q_from)[None], targets]), CONTROL_DT, axis=0)[1:]


def _action(
    bundle: Bundle,
    edge: int,
    q_now: np.ndarray,
    transit: np.ndarray,
    route: str,
    states_used: int = WHOLE,
    first: int = 0,
) -> Action:
    states = bundle.edge(edge, ("q", "qd"))
    transit = retime(q_now, transit, CONTROL_DT)  # at rest at each sharp corner
    q_edge = states["q"][first:states_used].astype(np.float64)
    qd_edge = states["qd"][first:states_used].astype(np.float64)
    qd_transit = transit_velocities(q_now, transit)
    return Action(
        edge=edge,
        q=np.concatenate([transit, q_edge]),
        qd=np.concatenate([qd_transit, qd_edge]),
        transit_steps=len(transit),
        via_park=route != "direct",
        route=route,
        edge_states=len(q_edge),
        edge_first=first,
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


def box_slots(nb: int) -> int:
    """Boxes in the clearance program for a scene of `nb` boxes: EDGE_BOXES (the edges'
    program: the same compilation) where they fit, else MAX_BOXES.  Each box's clearance is
    computed apart, so a scene's figures do not depend on the program; a small scene (the
    tunnel, clutter) pays for 4 boxes instead of 16."""
    return EDGE_BOXES if nb <= EDGE_BOXES else MAX_BOXES


def _box_kernel(robot: Robot, boxes: tuple[np.ndarray, np.ndarray, np.ndarray]):
    """jit(vmap(boxes_clearance)) over chunks of configurations, the scene's boxes shared
    (inputs: one program for every scene of as many boxes as `boxes` holds, padded; see
    `box_slots`)."""
    from .batching import ChunkedKernel, backend
    from .kernels.collision import boxes_clearance

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
