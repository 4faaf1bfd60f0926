"""Ways out for an arm that stands inside the scene's margins after a push: back along the
edge it came by (`retreat`), back along everything it followed (`trail_back`, for the
roadmap), or, wedged between objects the push moved, a beam search over small joint steps
that never goes deeper into any margin (`escape`).
"""

from __future__ import annotations

import numpy as np

from lmjx.planner.clearance import JAM_MARGIN, LEAVE_TOLERANCE
from lmjx.sim.sceneboxes import OBJECT_MARGIN

RETREAT_SLACK = 0.005  # a retreat backs out until the arm keeps this far outside the scene's margins [m]
RETREAT_STEP = 0.05  # the retreat's waypoints: at least this far apart (largest joint motion) [rad]
ESCAPE_STEP = 0.01  # the way out of a jam (`escape`): largest joint motion of one step [rad]
ESCAPE_STEPS = 100  # ... at most this many steps (rounds of its search)
ESCAPE_DIRS = 64  # ... directions tried at each step besides the free joints' own
ESCAPE_SCALES = (1.0, 0.5, 0.25)  # ... each at these fractions of ESCAPE_STEP
ESCAPE_BEAM = 32  # ... the search's paths kept each round
TRAIL_NODES = 1024  # the way back (`trail_back`): at most this many nodes, RETREAT_STEP apart (to the park pose)


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


class JamEscapes:
    """The ways out of the scene's margins (`retreat`, `escape`, `trail_back`).  A part of
    `TransitPlanner`, whose checks (`SceneChecks`) they use."""

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
        n, fine = self.segment_steps(dq, True)
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
            _, fine = self.segment_steps(dq, True)  # `_back_along`'s checks along each step
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

    def _trail_back(self, q_now: np.ndarray, trail: np.ndarray) -> np.ndarray:
        """`trail_back`, once per decision (Lazy asks one edge at a time)."""
        key = (q_now.tobytes(), len(trail), self.scene_version)
        return self._memo("_trail", key, lambda: self.trail_back(q_now, trail))
