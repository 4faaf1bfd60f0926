"""The search for feasible actions among the edges over the target, in their order
(`TransitPlanner.actions`, `TransitPlanner.search_actions`): the edges' starts and states
screened in batches, ahead of their use; the usable ones gathered, their transits searched
together (`TransitPlanner._ways`); the actions made in order, their states read at once.
Nothing here chooses among actions.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lmjx.mapfile.bundle import Bundle
from lmjx.planner.phases import PhaseClock
from lmjx.planner.timelaw import retime
from lmjx.planner.turned import TurnedEdges
from lmjx.types import CONTROL_DT, Action

# the search's tally of the edges it tested and why those not offered were not: the start
# blocked (the table, the arm itself, or within an object's or obstacle's margins), the edge
# itself unusable (cut short at a fixed obstacle, or not acting on the target), or no transit
# to its start
NO_ACTION_KEYS = ("tested", "start_blocked", "edge_unusable", "no_transit")
MIN_BLOCK = 32  # edges tested at a time when looking for feasible actions
SCREEN_AHEAD = 8192  # edges whose starts and states are tested at once on an accelerator (`lookahead`)
HOST_SCREEN = 256  # ... on the host
LATE_TRIES = 4  # `late_start`: edges with a blocked start tried per action still wanted


class ActionSearch:
    """The feasible actions among `edges`, in their order, found a few at a time
    (`TransitPlanner.actions`, `TransitPlanner.search_actions`): the edges screened ahead
    (`_Screened`), the usable ones gathered until there are as many as the actions still
    wanted (twice as many after a round that found too few), their transits searched at once
    (`TransitPlanner._ways`), the actions made in order.  A round's transits depend on the
    edges searched together only through the roadmap's shared checks, which find the same
    shortest free ways whoever asks (tests/test_transit_batched.py compares the whole search
    with the one-edge-at-a-time search it replaces)."""

    def __init__(
        self,
        tp: Any,  # the TransitPlanner searching (its checks, transits and caches)
        bundle: Bundle,
        edges: np.ndarray,
        q_now: np.ndarray,
        came_from: np.ndarray | None,
        trail: np.ndarray | None,
        clock: PhaseClock,
        block: int,
    ) -> None:
        self.tp, self.bundle, self.edges, self.trail, self.clock = tp, bundle, np.asarray(edges), trail, clock
        self.tally = dict.fromkeys(NO_ACTION_KEYS, 0)  # why edges were not offered (`last_tally`)
        self.q_arm, self.lead, self.q_from = q_now, np.zeros((0, len(q_now))), q_now  # where the arm is, what
        # it does first, where transits begin
        self.jammed = False  # inside the margins with no way back: transits may begin with the `escape`
        if came_from is not None and tp.scene is not None:

            def way_back() -> tuple[np.ndarray | None, bool]:  # the retreat, and whether the arm is jammed
                inside = bool(tp.scene_slack(q_now[None])[0] < 0)
                back = tp.retreat(q_now, came_from) if inside else None
                return back, inside and back is None

            key = (q_now.tobytes(), np.asarray(came_from).tobytes(), tp.scene_version)
            with clock.phase("transit"):
                back, self.jammed = tp._memo("_retreat", key, way_back)
            if back is not None:
                self.lead, self.q_from = back, back[-1]  # transits are planned from the retreat's end
        first = tp.lookahead(block)
        self.screened = _Screened(tp, bundle, self.edges, first, max(first, tp.screen_most()))
        self.i = 0  # edges[:i] are searched
        self.need = 0  # usable edges the next round gathers (0: as many as wanted)
        self.blocked_starts: list[np.ndarray] = []  # for `late_start`'s second pass

    def next(self, want: int, grow: bool = True) -> list[Action]:
        """The next `want` feasible actions (fewer where the edges run out).  `grow` False:
        gather one usable edge at a time (as many transits searched as actions wanted)."""
        out: list[Action] = []
        need = want
        while len(out) < want and self.i < len(self.edges):
            with self.clock.phase("offer"):
                # the cheapest test first (most edges over a target start where an object
                # stands), then the edges' own: until `need` edges pass both, or none is left
                i = self.i
                j, free, prefix = self.screened.gather(i, need)
                part = self.edges[i:j]
                self.tally["tested"] += j - i
                self.tally["start_blocked"] += int(len(part) - free.sum())
                if self.tp.late_start:
                    self.blocked_starts.append(part[~free])
                self.i = j
                part = part[free]
                self.tally["edge_unusable"] += int((prefix <= 0).sum())
                part, prefix = part[prefix > 0], prefix[prefix > 0]
            out += self._made(part, prefix, np.zeros(len(part), int), want - len(out))
            need = 2 * (want - len(out)) if grow else want - len(out)
        return out

    def late(self, want: int) -> list[Action]:
        """`late_start`'s second pass: edges whose start was blocked entered at their
        `late_starts`, at most LATE_TRIES of them per action still wanted, in order, a block
        at a time (twice the actions wanted, at least MIN_BLOCK)."""
        out: list[Action] = []
        # (at most LATE_TRIES per action wanted: a late start costs a test of every state of the edge)
        pool = np.concatenate(self.blocked_starts)[: LATE_TRIES * want]
        i, block = 0, max(MIN_BLOCK, 2 * want)
        while len(out) < want and i < len(pool):
            with self.clock.phase("offer"):
                part = np.asarray(pool[i : i + block])
                i += len(part)
                begin = self.tp.late_starts(self.bundle, part)
                free = begin > 0
                self.tally["start_blocked"] -= int(free.sum())
                part, begin = part[free], begin[free]
                prefix = self.tp.edge_prefixes(self.bundle, part, begin) if len(part) else np.zeros(0, int)
                self.tally["edge_unusable"] += int((prefix <= 0).sum())
                part, prefix, begin = part[prefix > 0], prefix[prefix > 0], begin[prefix > 0]
            out += self._made(part, prefix, begin, want - len(out))
            block = max(MIN_BLOCK, 2 * (want - len(out)))
        return out

    def _made(self, part: np.ndarray, prefix: np.ndarray, begin: np.ndarray, want: int) -> list[Action]:
        """The actions of the first `want` of the usable edges `part` that have a transit."""
        if not len(part):
            return []
        tp, bundle = self.tp, self.bundle
        with self.clock.phase("transit"):
            starts = bundle.q_start[part].astype(np.float64)
            late_ones = np.nonzero(begin)[0]
            if len(late_ones):
                q_late, lengths = bundle.states(part[late_ones], ("q",))
                firsts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
                starts[late_ones] = q_late["q"][firsts + begin[late_ones]]
            q_from = self.q_from
            ways = tp._ways(bundle, part, starts, list(range(len(part))), q_from, self.lead, self.trail)
            stuck = [j for j in range(len(part)) if j not in ways]
            if self.jammed and stuck:  # no way from where the arm stands: the same ways from the escape's end
                esc = tp._memo("_escape", (q_from.tobytes(), tp.scene_version), lambda: tp.escape(q_from))
                if esc is not None:
                    for j, (route, transit) in tp._ways(bundle, part, starts, stuck, esc[-1], esc, self.trail).items():
                        ways[j] = ("escape+" + route, transit)
            ok = sorted(ways)
            self.tally["no_transit"] += len(part) - len(ok)
            take = ok[:want]
            return _actions(bundle, part[take], self.q_arm, [ways[j] for j in take], prefix[take], begin[take])


class _Screened:
    """`TransitPlanner.actions`' first tests of its candidates, made ahead of their use
    (`lookahead` edges at a time): whether each edge's start is clear of the scene
    (`blocked`), and for those that are, how many of its states an action executes
    (`edge_prefixes`).  Each edge's figures are its own: screening more at once changes
    nothing but the number of calls."""

    def __init__(self, tp: Any, bundle: Bundle, edges: np.ndarray, lookahead: int, most: int) -> None:
        self.tp, self.bundle, self.edges, self.lookahead = tp, bundle, np.asarray(edges), lookahead
        self.ahead_most = most
        self.done = 0  # edges[:done] are screened
        self.free = np.zeros(len(self.edges), bool)
        self.prefix = np.zeros(len(self.edges), np.int64)

    def _screen(self, stop: int) -> None:
        """Screen edges[done:stop] (at least `lookahead` of them, where there are; each time
        twice as many as the time before, up to `ahead_most`: where few edges over the target
        are usable, a search screens its thousands in a few calls)."""
        stop = min(len(self.edges), max(stop, self.done + self.lookahead))
        self.lookahead = min(2 * self.lookahead, max(self.lookahead, self.ahead_most))
        part = self.edges[self.done : stop]
        free = ~self.tp.blocked(self.bundle.q_start[part].astype(np.float64))
        self.free[self.done : stop] = free
        if free.any():
            self.prefix[self.done : stop][free] = self.tp.edge_prefixes(self.bundle, part[free])
        self.done = stop

    def gather(self, a: int, need: int) -> tuple[int, np.ndarray, np.ndarray]:
        """From edge a on, as far as the `need`-th usable edge (a clear start and a prefix),
        or to the end where there are fewer: (the end b, whether each of edges[a:b] starts
        clear, the prefixes of those that do)."""
        b = a
        while True:
            usable = np.flatnonzero(self.free[a : self.done] & (self.prefix[a : self.done] > 0))
            if len(usable) >= need:
                b = a + int(usable[need - 1]) + 1
                break
            if self.done == len(self.edges):
                b = len(self.edges)
                break
            self._screen(self.done + need)
        free = self.free[a:b]
        return b, free, self.prefix[a:b][free]


def _actions(
    bundle: Bundle,
    edges: np.ndarray,
    q_now: np.ndarray,
    ways: list[tuple[str, np.ndarray]],
    states_used: np.ndarray,
    first: np.ndarray,
) -> list[Action]:
    """The actions of `edges` (their states read at once): each edge's transit (route, joint
    targets), retimed, then its states first[i] .. states_used[i] - 1."""
    if not len(edges):
        return []
    states, lengths = bundle.states(edges, ("q", "qd"))
    ends = np.cumsum(lengths)
    out = []
    for i, (route, transit) in enumerate(ways):
        a = int(ends[i] - lengths[i])
        used = slice(a + int(first[i]), a + min(int(states_used[i]), int(lengths[i])))
        transit = retime(q_now, transit, CONTROL_DT)  # at rest at each sharp corner
        q_edge = states["q"][used].astype(np.float64)
        qd_edge = states["qd"][used].astype(np.float64)
        edge, turn = int(edges[i]), 0.0
        if isinstance(bundle, TurnedEdges):
            edge, turn = bundle.source(edge)  # the map's edge and its turn
        out.append(
            Action(
                edge=edge,
                q=np.concatenate([transit, q_edge]),
                qd=np.concatenate([transit_velocities(q_now, transit), qd_edge]),
                transit_steps=len(transit),
                via_park=route != "direct",
                route=route,
                edge_states=len(q_edge),
                edge_first=int(first[i]),
                turn=turn,
            )
        )
    return out


def transit_velocities(q_from: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """The joint velocities (T, nj) the servos are given with joint targets (T, nj) that lead
    on from q_from at CONTROL_DT: differences of q_from then targets (central; the last
    one-sided)."""
    return np.gradient(np.concatenate([np.asarray(q_from)[None], targets]), CONTROL_DT, axis=0)[1:]
