"""The transit planner's search for actions as it read before it was batched: each edge's
states read one at a time, each turned edge's executed states checked by a call of their own,
each action made alone.  The reference that `lmjx.planner.transit.TransitPlanner.actions`
(which reads states in bulk, screens many blocks at once on an accelerator and checks every
turned edge in one batch) must match action for action (tests/test_transit_batched.py).
Everything else (the checks, the transits' routes, the roadmap) is the planner's own.
"""

from __future__ import annotations

import numpy as np

from lmjx.mapfile.bundle import Bundle
from lmjx.planner.search import LATE_TRIES, MIN_BLOCK, NO_ACTION_KEYS, transit_velocities
from lmjx.planner.timelaw import retime
from lmjx.planner.transit import ACT_DEPTH, WHOLE, TransitPlanner
from lmjx.planner.turned import TurnedEdges
from lmjx.sim.sceneboxes import EDGE_BOXES, FIXED_MARGIN, MIN_EDGE_STATES, box_kernel, cut_at_fixed
from lmjx.types import CONTROL_DT, Action


class ReferenceTransitPlanner(TransitPlanner):
    """`TransitPlanner` with the one-edge-at-a-time `actions`, `edge_prefixes` and `late_starts`."""

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
                self._edge_kernel = box_kernel(self.robot, self.scene.padded(EDGE_BOXES, keep))
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
        if isinstance(bundle, TurnedEdges):  # the base and the table do not turn: check what is executed
            for j in np.nonzero((prefix > 0) & (bundle.delta[np.asarray(edges, np.int64)] != 0))[0]:
                if self.colliding_batch(qs[j][begin[j] : prefix[j]].astype(np.float64)).any():
                    prefix[j] = 0
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

    def actions(
        self,
        bundle: Bundle,
        edges: np.ndarray,
        q_now: np.ndarray,
        want: int,
        came_from: np.ndarray | None = None,
        trail: np.ndarray | None = None,
        clock=None,  # (not timed here)
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

            key = (q_now.tobytes(), np.asarray(came_from).tobytes(), self.scene_version)
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
                    esc = self._memo("_escape", (q_now.tobytes(), self.scene_version), lambda: self.escape(q_now))
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
    turn = 0.0
    if isinstance(bundle, TurnedEdges):
        edge, turn = bundle.source(edge)  # the map's edge and its turn
    return Action(
        edge=edge,
        q=np.concatenate([transit, q_edge]),
        qd=np.concatenate([qd_transit, qd_edge]),
        transit_steps=len(transit),
        via_park=route != "direct",
        route=route,
        edge_states=len(q_edge),
        edge_first=first,
        turn=turn,
    )
