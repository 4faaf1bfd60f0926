"""Actions: the transit from the robot's current configuration to an edge's start, then the
edge itself, as joint targets at the control rate; and the servo controls a simulator
applies at its physics rate.

The transit is a straight line in joint space, timed so that no joint exceeds half its
velocity limit (a chain of lines slows to rest into each sharp corner and speeds up out of
it: `lmjx.planner.timelaw`, applied to the whole transit once it is built); when that line would
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
from typing import Any

import numpy as np

from lmjx.mapfile.bundle import Bundle
from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.planner.clearance import JAM_MARGIN, SceneChecks, park_pose
from lmjx.planner.escape import JamEscapes
from lmjx.planner.phases import PhaseClock
from lmjx.planner.roadmap import Roadmap
from lmjx.planner.search import HOST_SCREEN, MIN_BLOCK, SCREEN_AHEAD, ActionSearch
from lmjx.planner.turned import TurnedEdges
from lmjx.sim.sceneboxes import (
    EDGE_BOXES,
    FIXED_MARGIN,
    MIN_EDGE_STATES,
    OBJECT_MARGIN,
    box_kernel,
    cut_at_fixed,
    scene_boxes,
)
from lmjx.types import Action

ACT_DEPTH = 0.005  # an edge acts on the target when the arm sweeps this deep into its box [m]

MEMO_KEYS = 4  # per-decision caches (`_memo`): the latest this many keys

# (a call holds a median of about 40: a chunk of 256 cost 5.3 ms for 40 where 64 costs 1.1 ms)
OPTIONS_SAMPLE = 256  # `options`: edges whose starts it tests
OPTIONS_CHECK = 64  # `options`: clear ones whose states it tests
WHOLE = np.iinfo(np.int32).max  # `edge_prefixes` of an edge executed whole (no scene)


def after_executing(action: Action, trail: np.ndarray, dtype) -> tuple[np.ndarray, np.ndarray]:
    """What a trial keeps of an action it executed, for the transits that follow: the edge's
    states executed (`came_from`, in the map's precision `dtype`: a whole edge as it is
    stored), and `trail` extended by every joint target the arm followed."""
    return action.q[action.transit_steps :].astype(dtype), np.concatenate([trail, action.q])


class TransitPlanner(SceneChecks, JamEscapes):
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
        super().__init__(robot, batched)
        self.failure = failure
        self.speed = speed_fraction * robot.qd_max
        self.park = park_pose(robot, failure)
        self._edge_kernel = None
        self.scene_version: Any = 0  # the scene set, by content (`set_scene`): the caches' keys hold it
        self._forgotten = 0  # how often `forget` was called (part of every scene version since)
        self._to_park: dict = {}  # (where from, in which scene) -> the transit to the park pose (`_memo`)
        self._retreat: dict = {}  # (where from, along what, in which scene) -> (the retreat, jammed) (`_memo`)
        self._escape: dict = {}  # (where from, in which scene) -> the `escape` (`_memo`)
        self.last_tally: dict[str, int] = {}  # the last `actions` call's edges, by why they were not offered
        self._trail: dict = {}  # (where from, how long a trail, in which scene) -> `trail_back` (`_memo`)
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

        Trials run together (`lmjx.evaluation.lockstep`) share one TransitPlanner and each sets its own
        scene before it asks for actions, again after every simulation it waited for (another
        trial may have set its scene meanwhile).  Setting the scene that is already set
        changes nothing; a scene's version is its content's, so what was kept for a trial's
        scene (`_memo`) serves it again when it comes back to it."""
        objects = np.asarray(objects, np.float64)
        # the scene's content (Scenario is frozen), in this planner's memory since its last `forget`
        key = (self._forgotten, sc, objects.shape, objects.tobytes(), bool(acting))
        if self.scene is not None and key == self.scene_version:
            return
        self.place(scene_boxes(sc, objects))
        self.scene_version = key
        self.acting = acting
        self._from_park.clear()  # park -> start depends on where the objects are

    def forget(self) -> None:
        """Drop what was kept about the scenes set so far (the transits through the park pose,
        the ways out of a jam, the roadmaps' free nodes and links): the next `set_scene`
        starts afresh even for a scene already seen: every scene version from now on differs
        from those before, so nothing cached under one (`_memo`, the roadmaps) is found again."""
        for slot in ("_to_park", "_retreat", "_escape", "_trail"):
            getattr(self, slot).clear()
        self._forgotten += 1
        self.scene_version = 0

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
        states, lengths = bundle.states(edges, ("q",))
        q_all = states["q"].astype(np.float32)
        # the target and the fixed obstacles only (a program of EDGE_BOXES boxes), exactly
        # where the lower bound leaves it in doubt (near the target, near a fixed obstacle)
        keep = np.concatenate([[0], np.nonzero(fixed)[0]])
        # (an accelerator computes the exact clearance of everything faster than the host its bound)
        c = self.lower_bounds(q_all) if self._host_bounds else np.full((len(q_all), len(fixed)), -np.inf)
        doubt = (c[:, 0] <= -ACT_DEPTH) | np.any(c[:, fixed] < FIXED_MARGIN, axis=1)
        if doubt.any():
            if self._edge_kernel is None:
                self._edge_kernel = box_kernel(self.robot, self.scene.padded(EDGE_BOXES, keep))
            else:
                self._edge_kernel.set_shared(*self.scene.padded(EDGE_BOXES, keep))
            exact = self._edge_kernel.run(q_all[doubt])["box_clearance"][:, : len(keep)]
            rows = np.nonzero(doubt)[0]
            c[np.ix_(rows, keep)] = exact
        n = len(lengths)
        first = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        owner = np.repeat(np.arange(n), lengths)
        k = np.arange(len(owner)) - first[owner]  # each state's index within its edge
        begin = np.zeros(n, int) if first_state is None else np.asarray(first_state, int)
        counted = k >= begin[owner]
        prefix = cut_at_fixed(c[:, fixed].min(axis=1) if fixed.any() else None, owner, k, lengths, counted)
        if self.acting:  # (each edge's states are one run of rows: reduced per run)
            inside = counted & (k < prefix[owner])
            nearest = np.minimum.reduceat(np.where(inside, c[:, 0], np.inf), first) if n else np.zeros(0)
            prefix[nearest > -ACT_DEPTH] = 0
        prefix[prefix - begin < MIN_EDGE_STATES] = 0
        if isinstance(bundle, TurnedEdges):  # the base and the table do not turn: check what is executed
            turned = (prefix > 0) & (bundle.delta[np.asarray(edges, np.int64)] != 0)
            executed = turned[owner] & counted & (k < prefix[owner])
            if executed.any():  # every executed state of every turned edge in one batch
                hit = self.colliding_batch(q_all[executed].astype(np.float64))
                prefix[np.unique(owner[executed][hit])] = 0
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
        states, lengths = bundle.states(np.asarray(edges)[which], ("q",))
        free = ~self.blocked(states["q"].astype(np.float64))
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

    def actions(
        self,
        bundle: Bundle,
        edges: np.ndarray,
        q_now: np.ndarray,
        want: int,
        came_from: np.ndarray | None = None,
        trail: np.ndarray | None = None,
        clock: PhaseClock | None = None,
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
        them, in order, per action still wanted); their actions come after the others.
        `clock`: where the screening ("offer") and the transits ("transit") are timed."""
        search = self.search_actions(bundle, edges, q_now, came_from, trail, clock, want)
        out = search.next(want)
        if self.late_start and len(out) < want and search.blocked_starts:
            out += search.late(want - len(out))
        return out

    def search_actions(
        self,
        bundle: Bundle,
        edges: np.ndarray,
        q_now: np.ndarray,
        came_from: np.ndarray | None = None,
        trail: np.ndarray | None = None,
        clock: PhaseClock | None = None,
        block: int = 1,
    ) -> ActionSearch:
        """The search `actions` runs, to be taken a few actions at a time (`ActionSearch.next`:
        Lazy tries one, simulates it, then asks for the next); its tally is `last_tally`."""
        search = ActionSearch(self, bundle, edges, q_now, came_from, trail, clock or PhaseClock(), block)
        self.last_tally = search.tally
        return search

    def lookahead(self, block: int) -> int:
        """Edges whose starts and edges a search for `block` actions screens at once: on the
        host, where the checks cost per configuration and per call, eight per action wanted,
        from MIN_BLOCK to HOST_SCREEN; where the checks run on an accelerator (they cost per
        call), 256 per action wanted, up to `SCREEN_AHEAD`."""
        if self._host_bounds or not self.batched:
            return max(MIN_BLOCK, min(HOST_SCREEN, 8 * block))
        return max(block, min(SCREEN_AHEAD, 256 * block))

    def screen_most(self) -> int:
        """Edges a search screens at once at most, its screening grown (`_Screened`):
        HOST_SCREEN on the host, SCREEN_AHEAD on an accelerator."""
        return HOST_SCREEN if self._host_bounds or not self.batched else SCREEN_AHEAD

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
        """The roadmap over `bundle`'s edge starts (built on first use, kept per bundle; for
        turned edges, over their map's)."""
        bundle = bundle.base if isinstance(bundle, TurnedEdges) else bundle  # (over the map's own starts)
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
        first = self._memo("_to_park", (q_now.tobytes(), self.scene_version), lambda: self.to_park(q_now))
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
