"""The transit planner's search for actions, batched (states read in bulk, starts and edges
screened far ahead, the transits of many edges searched at once, every turned edge checked in
one batch), against the search as it read before (tests/reference_transit.py): the same
actions, in the same order, with the same transits and states, and where every edge was
tested, the same tally of what was not offered."""

from __future__ import annotations

import numpy as np
import pytest
from reference_transit import ReferenceTransitPlanner

from lmjx.mapfile.read import load_map
from lmjx.planner.edge_planner import edges_over_target
from lmjx.planner.transit import TransitPlanner
from lmjx.planner.turned import TurnedEdges, turn_axis, turned_over_target
from lmjx.sim.scenarios import resolve_task
from lmjx.sim.scene import build_scene, object_qpos


def _offered(robot, m, sc, objects, seed):
    """The planner's candidates over the target, in its order: the map's own edges, then the
    turned copies (`Planner._with_turned`)."""
    rng = np.random.default_rng(seed)
    half = float(sc.target.half[0])
    own = rng.permutation(edges_over_target(m.edges, m.reach, objects[0, :2], half, 0.01))
    ids, delta = turned_over_target(m.edges, m.reach, robot, m.failure, objects[0, :2], half, 0.01)
    mixed = rng.permutation(len(ids))
    view = TurnedEdges(m.edges, np.concatenate([own, ids[mixed]]), np.concatenate([np.zeros(len(own)), delta[mixed]]),
                       turn_axis(robot, m.failure))  # fmt: skip
    return view, np.arange(view.n_edges)


def _same(a, b) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert (x.edge, x.turn, x.route, x.transit_steps, x.edge_states, x.edge_first) == (
            y.edge, y.turn, y.route, y.transit_steps, y.edge_states, y.edge_first)  # fmt: skip
        assert np.array_equal(x.q, y.q) and np.array_equal(x.qd, y.qd)


@pytest.mark.parametrize("number", [1, 2, 3])
def test_batched_search_offers_the_actions_of_the_one_edge_at_a_time_search(robot, plan_map, number):
    """Each scenario's first decision, and the next one from where the first action left the
    arm (retreating along the edge it came by): in memory and from a lazily read map, with
    C MuJoCo's checks and (the third scenario) the clearance kernel's, the new search screening
    far ahead of its blocks."""
    task = resolve_task(number, robot, "paper")
    sc = task.scenario
    objects = object_qpos(build_scene(robot, sc), task.layout(number).poses)
    for lazy in (False, True):
        m = load_map(plan_map, lazy=lazy)
        view, order = _offered(robot, m, sc, objects, number)
        for batched in (False, True) if number == 3 and not lazy else (False,):
            new = TransitPlanner(robot, m.failure, batched=batched)
            new.lookahead = lambda block: max(block, 1024)  # type: ignore[method-assign]  (as on an accelerator)
            ref = ReferenceTransitPlanner(robot, m.failure, batched=batched)
            for tp in (new, ref):
                tp.set_scene(sc, objects)
            first = new.actions(view, order, new.park, 12)
            _same(first, ref.actions(view, order, ref.park, 12))
            assert first
            if len(first) < 12:  # every edge tested: the same tally (else each counts the edges it looked at)
                assert new.last_tally == ref.last_tally
            a = first[0]
            came_from, trail = a.q[a.transit_steps :], np.concatenate([new.park[None], a.q])
            after = new.actions(view, order, a.q[-1], 6, came_from, trail)
            _same(after, ref.actions(view, order, a.q[-1], 6, came_from, trail))
            if len(after) < 6:
                assert new.last_tally == ref.last_tally
        m.close()


def test_turned_edges_executed_states_are_checked_as_one_by_one(robot, plan_map):
    """The turned edges' executed states (from a late first state, up to where a fixed obstacle
    cuts them) checked in one batch: the same edges refused as when each is checked alone.
    The check is an oracle here that flags a band of base-joint angles (on the tests' map no
    turned copy comes near the base or the table's edge, which the real check finds)."""
    task = resolve_task(2, robot, "paper")
    sc = task.scenario
    objects = object_qpos(build_scene(robot, sc), task.layout(2).poses)
    m = load_map(plan_map)
    view, order = _offered(robot, m, sc, objects, 2)
    new, ref = TransitPlanner(robot, m.failure), ReferenceTransitPlanner(robot, m.failure)
    for tp in (new, ref):
        tp.set_scene(sc, objects)
        tp.colliding_batch = lambda q: np.abs(q[:, 0] - 0.3) < 0.05  # type: ignore[method-assign]
    cand = order[~new.blocked(view.q_start.astype(np.float64))]
    begin = np.random.default_rng(0).integers(0, 4, len(cand))
    got, want = new.edge_prefixes(view, cand, begin), ref.edge_prefixes(view, cand, begin)
    assert np.array_equal(got, want)
    ref.colliding_batch = lambda q: np.zeros(len(q), bool)  # type: ignore[method-assign]
    unchecked = ref.edge_prefixes(view, cand, begin)
    assert ((unchecked > 0) & (want == 0)).any() and (want > 0).any()  # the oracle refused some edges, not all
