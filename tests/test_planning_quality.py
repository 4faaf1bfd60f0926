"""The planner (Algorithm 3) at work on the planner tests' map: the agreement test's decisions,
planning quality against Random by a paired sign test (and its negative control), the ways
back, around and out (transits after a push, the roadmap, escapes of a jammed or wedged arm),
the push counts, the planning limit, the "real" world's unwatched steps."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from test_planning import arm_clearance_fn

from lmjx.mapfile.read import load_map
from lmjx.model.failure import parse_failure
from lmjx.planner.clearance import JAM_MARGIN, LEAVE_TOLERANCE, park_pose
from lmjx.planner.records import ENDS
from lmjx.planner.transit import TransitPlanner
from lmjx.planner.trial import run_trial, setup_trial
from lmjx.sim.cpu import CpuSimulator
from lmjx.sim.realworld import SimulatedRealWorld, real_physics
from lmjx.sim.scenarios import resolve_task, sample_layout, scenario
from lmjx.sim.scene import build_scene, object_qpos, read_objects, set_state
from lmjx.sim.sceneboxes import MIN_EDGE_STATES, OBJECT_MARGIN
from lmjx.types import CONTROL_DT, PlannerConfig


def test_the_agreement_tests_decisions_offer_the_planners_candidates(robot, plan_map):
    """The GPU simulator's agreement test (`lmjx.evaluation.agreement.decision_states`) decides among
    the planner's candidates: in every decision state (a trial's start, and after a random
    push) each candidate's edge starts OBJECT_MARGIN clear of the objects where they were
    observed, and from the park pose its whole transit does (C MuJoCo's mj_geomDistance)."""
    from lmjx.evaluation.agreement import decision_states
    from lmjx.sim.sceneboxes import OBJECT_MARGIN

    m = load_map(plan_map)
    decisions = decision_states(robot, {"case2": m}, (1,), 1, 2, 16, first_seed=5)
    assert [d.depth for d in decisions] == [0, 1]
    scene = build_scene(robot, scenario(1, tasks="hard"))
    d_mj = mujoco.MjData(scene.model)
    movable = [scene.model.geom(f"{b.name}_geom").id for b in scene.scenario.movable]
    clearance = arm_clearance_fn(robot, scene, d_mj)
    for dec in decisions:
        assert len(dec.actions) >= 2
        set_state(scene, d_mj, dec.observation.robot_q, dec.observation.objects)
        for a in dec.actions:
            assert clearance(a.q[a.transit_steps], movable) >= OBJECT_MARGIN - 1e-4
            if dec.depth == 0:
                assert min(clearance(q, movable) for q in a.q[: a.transit_steps : 2]) >= OBJECT_MARGIN - 1e-4


def test_the_agreement_tests_decisions_are_the_same_in_parallel(robot, plan_map, tmp_path):
    """`decision_states` with workers (spawned processes, JAX on the CPU in each: how the
    agreement test builds its 200-odd decisions on a GPU machine) makes the same decisions,
    in the same order, with the same candidates' joint targets as one process; and so do
    decisions written by `save_decisions` and read back (a CPU machine builds them for a GPU
    machine to measure), whose reader refuses any other file."""
    import gzip
    import pickle

    from lmjx.errors import ConfigError
    from lmjx.evaluation.agreement import decision_states, load_decisions, save_decisions

    m = load_map(plan_map)
    one = decision_states(robot, {"case2": m}, (1,), 2, 1, 8, first_seed=5)
    made = decision_states(robot, {"case2": m}, (1,), 2, 1, 8, first_seed=5, workers=2)
    save_decisions(tmp_path / "d.pkl.gz", (made, 1.5, 2), {"case2": m}, 2)
    blob = load_decisions(tmp_path / "d.pkl.gz")
    two = blob["decisions"]
    assert (blob["seconds"], blob["workers"], blob["seeds"], blob["maps"]["case2"]["edges"]) == (
        1.5,
        2,
        2,
        m.edges.n_edges,
    )
    (tmp_path / "other.gz").write_bytes(b"not a pickle")
    with pytest.raises(ConfigError, match="not a decisions file"):
        load_decisions(tmp_path / "other.gz")
    with gzip.open(tmp_path / "dict.gz", "wb") as fh:  # a pickle, but not of decisions
        pickle.dump({"decisions": made}, fh)
    with pytest.raises(ConfigError, match="not a decisions file of"):
        load_decisions(tmp_path / "dict.gz")
    assert [(d.seed, d.depth) for d in one] == [(d.seed, d.depth) for d in two] == [(5, 0), (6, 0)]
    for a, b in zip(one, two, strict=True):
        np.testing.assert_array_equal(a.observation.objects, b.observation.objects)
        assert [x.edge for x in a.actions] == [x.edge for x in b.actions]
        assert all(np.array_equal(x.q, y.q) for x, y in zip(a.actions, b.actions, strict=True))


def begins_along(q: np.ndarray, way: np.ndarray) -> int:
    """How many of the joint targets q (an action's) lead along the polyline `way` to its end
    (every one of them on it, to 1e-9 rad; the last equal to way[-1]): `lmjx.planner.timelaw.retime`
    changes when the arm reaches each point of a transit's path, not the path."""
    ends = np.nonzero(np.all(np.abs(q - way[-1]) <= 1e-12, axis=1))[0]
    assert len(ends), "the path's end is never reached"
    seg = way[1:] - way[:-1]
    length2 = np.maximum(np.einsum("ij,ij->i", seg, seg), 1e-30)
    for p in q[: ends[0] + 1]:
        f = np.clip(np.einsum("ij,ij->i", p - way[:-1], seg) / length2, 0, 1)
        assert np.min(np.abs(way[:-1] + f[:, None] * seg - p).max(axis=1)) < 1e-9
    return int(ends[0]) + 1


def test_after_a_push_transits_back_out_along_the_edge(robot, plan_map):
    """An edge that pushed the target leaves the arm inside the scene's margins; the next
    actions' transits then begin with the same retreat back along that edge, on which the
    arm's clearance to the scene (C MuJoCo's mj_geomDistance, objects where the "real" world
    was observed after the push) never falls more than LEAVE_TOLERANCE below where it stood,
    and which ends RETREAT_SLACK outside every margin."""
    from lmjx.planner.clearance import LEAVE_TOLERANCE
    from lmjx.planner.edge_planner import edges_over_target
    from lmjx.planner.escape import RETREAT_SLACK
    from lmjx.sim.sceneboxes import OBJECT_MARGIN

    m = load_map(plan_map)
    sc = scenario(1, tasks="hard")
    layout = sample_layout(sc, 5)
    tp = TransitPlanner(robot, m.failure, batched=True)
    world = SimulatedRealWorld(robot, 5)
    obs = world.reset(layout, tp.park)
    tp.set_scene(sc, obs.objects)
    first = tp.actions(m.edges, edges_over_target(m.edges, m.reach, obs.objects[0, :2], 0.05, 0.01), obs.robot_q, 1)
    assert first
    obs = world.execute(first[0])
    scene = build_scene(robot, sc)
    d = mujoco.MjData(scene.model)
    set_state(scene, d, obs.robot_q, obs.objects)  # the objects where the planner sees them
    clearance = arm_clearance_fn(robot, scene, d)
    movable = [scene.model.geom(f"{b.name}_geom").id for b in sc.movable]

    def slack(q):
        return clearance(q, movable) - OBJECT_MARGIN  # scenario 1 has no fixed obstacle

    assert slack(obs.robot_q) < 0  # this push ends inside the margins
    tp.set_scene(sc, obs.objects)
    came_from = m.edges.edge(first[0].edge, ("q",))["q"]
    edges = edges_over_target(m.edges, m.reach, obs.objects[0, :2], 0.05, 0.01)
    acts = tp.actions(m.edges, edges, obs.robot_q, 3, came_from)
    assert acts
    lead = tp.retreat(obs.robot_q, came_from)
    assert lead is not None
    way = np.concatenate([obs.robot_q[None], lead])  # the retreat's path (retimed, not reshaped)
    for a in acts:
        k = begins_along(a.q, way)
        assert np.array_equal(a.q[:k], acts[0].q[:k])  # every transit begins the same way
    s = np.array([slack(q) for q in lead])
    assert s.min() >= min(slack(obs.robot_q), 0.0) - LEAVE_TOLERANCE - 1e-4
    assert s[-1] >= RETREAT_SLACK - 1e-4


def sign_test_p(wins: int, losses: int) -> float:
    """One-sided paired sign test: P(at least `wins` of wins + losses under a fair coin)."""
    import math

    n = wins + losses
    return sum(math.comb(n, k) for k in range(wins, n + 1)) / 2**n if n else 1.0


def paired_decisions(
    robot, small_map, greedy_pick=None, seeds=range(40, 70), **greedy
) -> list[tuple[float, float, bool]]:
    """For 30 seeded trial starts (scenario 1, seeds 40-69; used by no other test):
    Greedy's action and Random's on the same observed state, each executed in a fresh
    "real" world of that seed; the target's path length to the goal after each, and whether
    any transit touched a fixed obstacle.  `greedy_pick` replaces Greedy's choice among its
    simulated candidates (to show that the test notices); `greedy`: Greedy's settings apart
    from the defaults.  (Why 30 starts: at 15 a single pair decided the test, 12 wins to 3,
    p = 0.018, with rescoring on; over 40 starts rescoring on and off both win 29 to 4.)
    Greedy simulates with its servo model (`PlannerConfig.servo`, "robot" by default)."""
    from lmjx.planner.edge_planner import Planner
    from lmjx.planner.trial import planner_physics

    m = load_map(small_map)
    transits = TransitPlanner(robot, m.failure)
    out = []
    for number in (1,):
        sc = scenario(number, tasks="hard")
        # the planner's simulator as `lmjx plan` makes it: with Greedy's servo model
        sim = CpuSimulator(build_scene(robot, sc, planner_physics(robot, PlannerConfig(**greedy).servo)))
        planners = {}
        for asm in ("greedy", "random"):
            config = PlannerConfig(asm=asm, greedy_candidates=8, **(greedy if asm == "greedy" else {}))
            planners[asm] = Planner(robot, m.failure, m.reach, m.edges, sc, sim if asm == "greedy" else None, config,
                                    transits)  # fmt: skip
        if greedy_pick is not None:
            planners["greedy"].best_of = greedy_pick
        closeness = planners["random"].field  # the path length to the goal, for both (Greedy's own
        # score may weigh it by the map's pushes: `PlannerConfig.push_weight`)
        for seed in seeds:
            layout = sample_layout(sc, seed)
            obs = SimulatedRealWorld(robot, seed).reset(layout, transits.park)
            after, fixed = {}, False
            for asm, planner in planners.items():
                action, _ = planner.choose(obs, np.random.default_rng(seed))
                world = SimulatedRealWorld(robot, seed)
                world.reset(layout, transits.park)
                if action is None:
                    after[asm] = float(closeness(world.truth()[0, :2]))
                    continue
                done = world.execute(action)
                fixed |= done.transit_hit_fixed
                after[asm] = float(closeness(world.truth()[0, :2]))
            out.append((after["greedy"], after["random"], fixed))
    return out


def test_greedy_leaves_the_target_closer_than_random(robot, plan_map):
    """Planning quality: on the same observed states, the action Greedy picks (8 candidates
    simulated in C MuJoCo), executed in the "real" world, leaves the target closer to the
    goal than Random's pick, by a paired sign test at p < 0.01 (pairs within 1 mm are ties);
    and no transit of either touches a fixed obstacle."""
    pairs = paired_decisions(robot, plan_map)
    wins = sum(g < r - 1e-3 for g, r, _ in pairs)
    losses = sum(g > r + 1e-3 for g, r, _ in pairs)
    assert sign_test_p(wins, losses) < 0.01, (wins, losses, pairs)
    assert not any(f for _, _, f in pairs)


def test_a_random_pick_in_greedys_place_fails_the_sign_test(robot, plan_map):
    """The planning-quality test's negative control: with Greedy's choice among its simulated
    candidates replaced by a uniformly random one (a stream seeded once, so the same picks
    every run), the same 30 decision states and the same sign test do not find it better
    than Random's pick (p >= 0.01): the test's pass comes from Greedy's choice, not from
    its candidates or the test itself.  Rescoring is off here (a random pick ignores the
    scores it would average), so Greedy simulates only its 8 candidates."""
    picks = np.random.default_rng(4242)
    pairs = paired_decisions(robot, plan_map, greedy_pick=lambda s, _rng: int(picks.integers(len(s))), rescore_top=0)
    wins = sum(g < r - 1e-3 for g, r, _ in pairs)
    losses = sum(g > r + 1e-3 for g, r, _ in pairs)
    assert len(pairs) == 30 and wins + losses >= 10, (wins, losses, pairs)  # enough decided pairs to tell
    assert sign_test_p(wins, losses) >= 0.01, (wins, losses, pairs)


def test_a_blocked_way_to_park_goes_around_the_objects(robot, plan_map):
    """Where the straight line to the park pose is blocked (a cube placed where the arm
    passes halfway), `to_park` finds a dog-leg (some joints first, then the rest) that ends
    at the park pose and keeps its margin from every movable object at every control step,
    by C MuJoCo's mj_geomDistance; the table and the arm itself stay clear too (C MuJoCo's
    contacts)."""
    from lmjx.planner.clearance import JAM_MARGIN
    from lmjx.sim.sceneboxes import OBJECT_MARGIN

    m = load_map(plan_map)
    sc = scenario(1, tasks="hard")
    scene = build_scene(robot, sc)
    model, d = scene.model, mujoco.MjData(scene.model)
    tp = TransitPlanner(robot, m.failure, batched=True)
    starts = m.edges.q_start[:400].astype(np.float64)
    starts = starts[~tp.colliding_batch(starts)]
    q0 = starts[np.argmax(np.abs(starts - tp.park).max(axis=1))]
    far = np.array([[5.0 + k, 5.0, 0.5, 1.0, 0.0, 0.0, 0.0] for k in range(len(sc.movable))])
    set_state(scene, d, (q0 + tp.park) / 2, far)
    tcp = model.site(robot.mj.site(robot.tcp_site).name).id
    objects = far.copy()
    objects[0, :3] = d.site_xpos[tcp]  # the target, where the arm's hand passes halfway
    tp.set_scene(sc, objects, acting=False)
    assert tp.segment(q0, tp.park) is None
    path = tp.to_park(q0)
    assert path is not None and np.allclose(path[-1], tp.park)
    set_state(scene, d, q0, objects)
    clearance = arm_clearance_fn(robot, scene, d)
    movable = [model.geom(f"{b.name}_geom").id for b in sc.movable]
    gaps = np.array([clearance(q, movable) for q in path])
    # the start keeps its margin, so no leg needed the jam's reduced one
    assert clearance(q0, movable) >= OBJECT_MARGIN and gaps.min() >= OBJECT_MARGIN - 1e-4 > JAM_MARGIN
    for q in path[::5]:
        d.qpos[scene.robot_qpos] = q
        mujoco.mj_forward(model, d)
        assert not any(
            model.geom_bodyid[c.geom1] != model.geom_bodyid[c.geom2] and c.dist < 0 for c in d.contact[: d.ncon]
        )


def _cube_between_two_starts(robot, plan_map):
    """Two edge starts of the planner tests' map far apart, and a cube where the straight
    line between them passes halfway (scenario 1's other objects far away), set as the
    scene of a batched TransitPlanner: (map, transits, q0, q1, check) where check(path)
    asserts that a path from q0 keeps OBJECT_MARGIN from the cube at every control step by C
    MuJoCo's mj_geomDistance, touches neither the table nor the arm itself (C MuJoCo's
    contacts) and moves no joint faster than the transits' speed."""
    from lmjx.sim.sceneboxes import OBJECT_MARGIN

    m = load_map(plan_map)
    sc = scenario(1, tasks="hard")
    scene = build_scene(robot, sc)
    model, d = scene.model, mujoco.MjData(scene.model)
    tp = TransitPlanner(robot, m.failure, batched=True)
    starts = m.edges.q_start[:400].astype(np.float64)
    starts = starts[~tp.colliding_batch(starts)]
    far_apart = np.abs(starts[:, None] - starts[None]).max(axis=-1)
    i, j = np.unravel_index(np.argmax(far_apart), far_apart.shape)
    q0, q1 = starts[i], starts[j]
    far = np.array([[5.0 + k, 5.0, 0.5, 1.0, 0.0, 0.0, 0.0] for k in range(len(sc.movable))])
    set_state(scene, d, (q0 + q1) / 2, far)
    objects = far.copy()
    objects[0, :3] = d.site_xpos[model.site(robot.mj.site(robot.tcp_site).name).id]
    tp.set_scene(sc, objects, acting=False)

    def check(path: np.ndarray) -> None:
        set_state(scene, d, q0, objects)
        clearance = arm_clearance_fn(robot, scene, d)
        target = [model.geom(f"{sc.movable[0].name}_geom").id]
        assert min(clearance(q, target) for q in path) >= OBJECT_MARGIN - 1e-4
        for q in path:
            d.qpos[scene.robot_qpos] = q
            mujoco.mj_forward(model, d)
            assert not any(
                model.geom_bodyid[c.geom1] != model.geom_bodyid[c.geom2] and c.dist < 0 for c in d.contact[: d.ncon]
            )
        step = np.abs(np.diff(np.concatenate([q0[None], path]), axis=0)).max(axis=0)
        assert np.all(step <= tp.speed * CONTROL_DT * (1 + 1e-9))

    return m, tp, q0, q1, check


def test_a_roadmap_transit_goes_around_what_blocks_the_straight_line(robot, plan_map):
    """Where a cube stands where the straight line between two edge starts passes halfway,
    the roadmap (`lmjx.planner.roadmap`, over the map's edge starts) finds a way from one to the
    other that ends at the goal, keeps OBJECT_MARGIN from the cube at every control step by
    C MuJoCo's mj_geomDistance, touches neither the table nor the arm itself (C MuJoCo's
    contacts), and moves no joint faster than the transits' speed."""
    m, tp, q0, q1, check = _cube_between_two_starts(robot, plan_map)
    assert tp.segment(q0, q1) is None
    path = tp.roadmap(m.edges).transits(q0, q1[None])[0]
    assert path is not None and np.allclose(path[-1], q1)
    check(path)


def test_the_way_back_leads_out_where_the_roadmap_has_no_way(robot, plan_map):
    """The arm may stand where no roadmap node has a clear line (after a push, in a tunnel):
    the way it came (`TransitPlanner.trail_back`, from every joint target it followed) then
    leads out.  Here: the cube of the test above, the arm at one start having come from the
    other around the cube (a path the full roadmap found); a roadmap of the park pose alone
    finds no way back to the other start, with the trail it finds one that ends there and
    passes the same checks (C MuJoCo's clearance and contacts, the transits' speed).  The
    trail's nodes are its own states, RETREAT_STEP apart, from the latest nearest the arm
    backwards."""
    from lmjx.planner.escape import RETREAT_STEP, TRAIL_NODES
    from lmjx.planner.roadmap import Roadmap

    m, tp, q0, q1, check = _cube_between_two_starts(robot, plan_map)
    came = tp.roadmap(m.edges).transits(q1, q0[None])[0]  # how the arm came from q1 to q0
    assert came is not None and tp.segment(q0, q1) is None
    trail = np.concatenate([q1[None], came])
    back = tp.trail_back(q0, trail)
    assert 0 < len(back) <= TRAIL_NODES
    assert all(np.any(np.all(trail == b, axis=1)) for b in back)  # its own states
    steps = np.abs(np.diff(np.concatenate([q0[None], back]), axis=0)).max(axis=1)
    assert np.all(steps >= RETREAT_STEP - 1e-12)
    alone = Roadmap(tp, tp.park[None])  # the park pose, and nothing else
    assert alone.transits(q0, q1[None])[0] is None
    path = alone.transits(q0, q1[None], back)[0]
    assert path is not None and np.allclose(path[-1], q1)
    check(path)


def assert_escape_keeps_clear(robot, failure, scene, d, clearance, objects, q0, path, object_contacts=True) -> None:
    """The checks of an `escape` path by C MuJoCo: its clearance to each of `objects` (geom
    ids; `clearance`, `arm_clearance_fn`'s) never falls more than LEAVE_TOLERANCE below where
    it began or JAM_MARGIN (whichever is lower) and ends at least OBJECT_MARGIN; the locked
    joints and the joint limits are kept; no contact between different bodies at any of its
    states (`object_contacts` False: none but with the objects)."""
    model = scene.model
    for g in objects:  # each object against where the arm began beside it
        gaps = np.array([clearance(q, [g]) for q in path])
        began = clearance(q0, [g])
        assert gaps.min() >= min(began, JAM_MARGIN) - LEAVE_TOLERANCE - 1e-4, model.geom(g).name
        assert gaps[-1] >= OBJECT_MARGIN - 1e-4, model.geom(g).name
    locked = [j - 1 for j in failure.locked_joints]
    np.testing.assert_array_equal(path[:, locked], np.repeat(q0[None, locked], len(path), axis=0))
    assert np.all(path >= robot.lower) and np.all(path <= robot.upper)
    skip = set() if object_contacts else set(objects)
    for q in path:
        d.qpos[scene.robot_qpos] = q
        mujoco.mj_forward(model, d)
        assert not any(
            model.geom_bodyid[c.geom1] != model.geom_bodyid[c.geom2] and c.dist < 0 and not {c.geom1, c.geom2} & skip
            for c in d.contact[: d.ncon]
        )


def test_a_jammed_arm_escapes_without_going_deeper(robot, plan_map, monkeypatch):
    """A push can leave the arm inside the scene's margins with no way back along its edge
    (`retreat` finds none: here the edge is the arm's own pose alone, the hand between two
    objects).  `escape` then takes
    it out: by C MuJoCo's mj_geomDistance its clearance to the objects never falls more than
    LEAVE_TOLERANCE below where it stood or JAM_MARGIN (whichever is lower) at any control
    step, and ends at least OBJECT_MARGIN clear; the table and the arm itself stay clear (C
    MuJoCo's contacts), the locked joints and the joint limits are kept.  Edges with no
    transit from where the arm stands are offered after it ("escape+..." routes, the escape
    first); the others exactly as when the arm is not jammed.  Transits from the escape's end
    begin with it, end at their edge's start and keep OBJECT_MARGIN after it."""

    m = load_map(plan_map)
    sc = scenario(1, tasks="hard")
    scene = build_scene(robot, sc)
    model, d = scene.model, mujoco.MjData(scene.model)
    tp = TransitPlanner(robot, m.failure, batched=True, search=False)  # (no roadmap: cheaper, the same checks)
    starts = m.edges.q_start[:400].astype(np.float64)
    q0 = starts[~tp.colliding_batch(starts)][7]
    objects = np.array([[5.0 + k, 5.0, 0.5, 1.0, 0.0, 0.0, 0.0] for k in range(len(sc.movable))])
    set_state(scene, d, q0, objects)
    clearance = arm_clearance_fn(robot, scene, d)
    movable = [model.geom(f"{b.name}_geom").id for b in sc.movable]
    hand = d.site_xpos[model.site(robot.mj.site(robot.tcp_site).name).id].copy()
    for k, side in ((0, 1.0), (1, -1.0)):  # the target on one side of the hand, an object on the other,
        lo, hi = 0.0, 0.3  # each 6 mm from the arm: the arm wedged inside both margins
        for _ in range(40):
            objects[k, :3] = hand + np.array([side * (lo + hi) / 2, 0.0, 0.0])
            set_state(scene, d, q0, objects)
            lo, hi = ((lo + hi) / 2, hi) if clearance(q0, movable[k : k + 1]) < 0.006 else (lo, (lo + hi) / 2)
    start = clearance(q0, movable)
    assert 0.005 < start < OBJECT_MARGIN and clearance(q0, movable[1:2]) < OBJECT_MARGIN
    tp.set_scene(sc, objects)
    assert tp.retreat(q0, q0[None]) is None
    path = tp.escape(q0)
    assert path is not None
    assert_escape_keeps_clear(robot, m.failure, scene, d, clearance, movable[:2], q0, path)  # the two beside it
    edges = np.arange(10)  # edges anywhere (not only over the target: `acting` off)
    tp.set_scene(sc, objects, acting=False)
    acts = tp.actions(m.edges, edges, q0, len(edges), q0[None])  # jammed: the escape for edges with no way
    plain = {a.edge: a for a in tp.actions(m.edges, edges, q0, len(edges))}  # not jammed: no escape
    assert plain and len(acts) >= len(plain)
    for a in acts:
        if a.route.startswith("escape+"):
            assert a.edge not in plain
            begins_along(a.q, np.concatenate([q0[None], path]))  # the escape's path, retimed
        else:
            np.testing.assert_allclose(a.q, plain[a.edge].q, rtol=0, atol=1e-12)
    # the transits after the escape, for edges that have one from where the arm stands too:
    # they begin with the escape, end at the edge's start and keep the full margin after it
    part = np.array(sorted(plain))[:3]
    starts = m.edges.q_start[part].astype(np.float64)
    after = tp._ways(m.edges, part, starts, list(range(len(part))), path[-1], path, None)  # from the escape's end
    assert after
    for j, (route, transit) in after.items():
        assert route in ("direct", "park")
        np.testing.assert_array_equal(transit[: len(path)], path)
        np.testing.assert_allclose(transit[-1], starts[j], atol=1e-9)
        assert min(clearance(q, movable) for q in transit[len(path) :]) >= OBJECT_MARGIN - 1e-4
    # where no edge has a transit from where the arm stands (every straight line from q0
    # refused, so neither a direct transit nor a way to the park pose), the edges are offered
    # after the escape, in their order
    segments = tp.segments

    def none_from_q0(a, b):
        return [None if np.array_equal(x, q0) else w for x, w in zip(a, segments(a, b), strict=True)]

    monkeypatch.setattr(tp, "segments", none_from_q0)
    tp.forget()  # nothing kept from above (found before `segments` was replaced)
    tp.set_scene(sc, objects, acting=False)
    assert not tp.actions(m.edges, edges, q0, len(edges))  # not jammed: nothing
    jam = tp.actions(m.edges, edges, q0, len(edges), q0[None])
    assert jam and all(a.route.startswith("escape+") for a in jam)
    assert [a.edge for a in jam] == sorted(a.edge for a in jam)
    for a in jam:
        begins_along(a.q, np.concatenate([q0[None], path]))


# the hard set's trial 1005 (case 1, clutter, Greedy), after its first push: where the arm
# stood and the objects as the planner observed them (recorded by replaying the trial)
WEDGE_Q = [-2.094585191469385, -0.38554973939259163, 2.877191123935564, -2.5755576106222784,
           0.00039133548716256667, 2.9814477112460755, 0.7860328914256102]  # fmt: skip
WEDGE_OBJECTS = [
    [0.4127834366540514, 0.2777647783774223, 0.025, 0.873692545303924, 0.0, 0.0, 0.48647850546591526],
    [0.5011393493266814, 0.42570141243210796, 0.03, 0.9947403004451251, 0.0, 0.0, -0.10242916904057353],
    [0.3210939031671714, 0.2852012053536455, 0.03, 0.993220584019228, 0.0, 0.0, 0.11624487722262705],
    [0.44897375617179014, 0.44446173094420144, 0.03, 0.7751124655293, 0.0, 0.0, 0.6318232868303365],
]


def test_a_wedged_arm_escapes_by_search(robot, monkeypatch):
    """Trial 1005's wedge: a push left the arm between the target it pushed (2.4 mm clear of
    it) and obstacle2 (2.2 mm into its observed box), the park pose blocked.  A greedy walk
    (`escape` with a beam of one) dead-ends there: every step from its second state goes
    deeper into something.  The beam search gets out: by C MuJoCo's mj_geomDistance the arm
    never comes nearer any object than it began or than JAM_MARGIN (whichever is lower;
    LEAVE_TOLERANCE), ends at least OBJECT_MARGIN clear of every object, touches neither the
    table nor itself, and keeps its locked joints and joint limits."""
    import lmjx.planner.escape as escape

    q0, objects = np.array(WEDGE_Q), np.array(WEDGE_OBJECTS)
    failure = parse_failure("case1", robot)
    sc = scenario(1, tasks="hard")
    scene = build_scene(robot, sc)
    model, d = scene.model, mujoco.MjData(scene.model)
    set_state(scene, d, q0, objects)
    clearance = arm_clearance_fn(robot, scene, d)
    movable = [model.geom(f"{b.name}_geom").id for b in sc.movable]
    began = np.array([clearance(q0, [g]) for g in movable])
    assert began[0] < OBJECT_MARGIN and began[2] < 0.001  # wedged: the target and obstacle2 within reach
    tp = TransitPlanner(robot, failure, batched=True, search=False)
    tp.set_scene(sc, objects)
    assert tp.to_park(q0) is None
    path = tp.escape(q0)
    assert path is not None
    # (it began 2.2 mm into obstacle2's box: contacts with the objects are their clearances' to judge)
    assert_escape_keeps_clear(robot, failure, scene, d, clearance, movable, q0, path, object_contacts=False)
    monkeypatch.setattr(escape, "ESCAPE_BEAM", 1)  # the greedy walk
    tp.forget()
    tp.set_scene(sc, objects)
    assert tp.escape(q0) is None


def _observed(robot, sc, seed: int) -> np.ndarray:
    """(n, 7) the objects of a seeded layout of `sc` as the planner observes them."""
    scene = build_scene(robot, sc)
    d = mujoco.MjData(scene.model)
    q = park_pose(robot, parse_failure("case2", robot))
    set_state(scene, d, q, object_qpos(scene, sample_layout(sc, seed).poses))
    mujoco.mj_kinematics(scene.model, d)
    return read_objects(scene, d)


def test_options_estimate_what_actions_would_offer_before_transits(robot, plan_map):
    """`TransitPlanner.options` with every edge sampled and checked is exactly the number of
    edges over the target that `actions` finds neither start-blocked nor unusable (its tally);
    a sample of them estimates it within four binomial standard errors."""
    from lmjx.planner.edge_planner import edges_over_target

    m = load_map(plan_map)
    sc = scenario(1, tasks="hard")
    objects = _observed(robot, sc, 3)
    tp = TransitPlanner(robot, m.failure, batched=True)
    tp.set_scene(sc, objects)
    edges = edges_over_target(m.edges, m.reach, objects[0, :2], float(sc.target.half[0]), 0.01)
    tp.actions(m.edges, edges, tp.park, len(edges))
    t = tp.last_tally
    assert t["tested"] == len(edges)
    offered = len(edges) - t["start_blocked"] - t["edge_unusable"]
    assert 0 < offered < len(edges)
    rng = np.random.default_rng(0)
    assert tp.options(m.edges, edges, rng, sample=len(edges), check=len(edges)) == pytest.approx(offered)
    n = len(edges) // 2
    est = tp.options(m.edges, edges, rng, sample=n, check=n)
    p = offered / len(edges)
    assert abs(est - offered) <= 4 * len(edges) * np.sqrt(p * (1 - p) / n) + 1e-9
    assert tp.options(m.edges, edges[:0], rng) == 0.0


def test_greedy_stuck_takes_the_candidate_that_leaves_the_most_options(robot, plan_map):
    """when_stuck="options": of the candidates that keep every object on the table, those
    with at least OPTIONS_NEAR of the most options qualify, and the best predicted of them is
    taken; the record keeps both figures.  With "best" a decision is unchanged."""
    from lmjx.planner.edge_planner import Planner, edges_over_target
    from lmjx.planner.scoring import OFF_TABLE_PENALTY
    from lmjx.types import OPTIONS_NEAR

    m = load_map(plan_map)
    setup = setup_trial(robot, m, resolve_task(1, robot, "hard"), PlannerConfig(asm="greedy", when_stuck="options"), 3)
    planner: Planner = setup.planner
    sc = planner.sc
    base = _observed(robot, sc, 3)
    predicted = np.repeat(base[None], 6, axis=0)
    for i, dx in enumerate((0.0, 0.03, -0.03, 0.06, -0.06, 0.09)):  # the target moved along x
        predicted[i, 0, 0] += dx
    tp = planner.transits
    opts = []
    for i in range(5):
        tp.set_scene(sc, predicted[i])
        e = edges_over_target(m.edges, m.reach, predicted[i, 0, :2], float(sc.target.half[0]), 0.01)
        opts.append(tp.options(m.edges, e, np.random.default_rng(len(e))))
    opts = np.array(opts)
    qualify = np.nonzero(opts >= OPTIONS_NEAR * opts.max())[0]
    assert 0 < len(qualify) < 5  # some candidates do not qualify: the rule is put to the test
    # the fewer options, the better predicted: the best predicted does not qualify
    scores = np.append(0.20 + 0.01 * np.argsort(np.argsort(opts)), OFF_TABLE_PENALTY + 0.1)
    best, rec = planner._most_options(predicted, scores)
    assert best == qualify[np.argmin(scores[qualify])] and best != 5
    assert rec["options"] == pytest.approx(opts[best], abs=0.05)
    assert rec["most_options"] == pytest.approx(opts.max(), abs=0.05)
    assert rec["predicted_m"] == pytest.approx(scores[best]) and rec["best_predicted_m"] == pytest.approx(0.20)
    assert PlannerConfig().when_stuck == "best"
    with pytest.raises(Exception, match="when stuck"):
        PlannerConfig(when_stuck="wander").validate()


def test_a_small_scene_is_checked_by_the_small_program_with_the_same_figures(robot, plan_map):
    """A scene of up to EDGE_BOXES boxes (the tunnel: the target and three fixed boxes) is
    checked by the 4-box clearance program the edges use, not the MAX_BOXES one: the same
    clearances, to float32 rounding, for configurations spanning several chunks."""
    from lmjx.sim.sceneboxes import EDGE_BOXES, MAX_BOXES, box_kernel, box_slots

    assert box_slots(EDGE_BOXES) == EDGE_BOXES and box_slots(EDGE_BOXES + 1) == MAX_BOXES
    m = load_map(plan_map)
    sc = scenario(2, tasks="hard")
    tp = TransitPlanner(robot, m.failure, batched=True)
    tp.set_scene(sc, _observed(robot, sc, 5))
    assert len(tp.scene.names) == EDGE_BOXES
    qs = np.concatenate([m.edges.edge(e)["q"] for e in range(40)]).astype(np.float32)
    small = tp.box_clearance(qs)
    big = box_kernel(robot, tp.scene.padded(MAX_BOXES)).run(qs)["box_clearance"][:, :EDGE_BOXES]
    assert len(qs) > 256 and small.shape == big.shape
    np.testing.assert_allclose(small, big, rtol=0, atol=1e-6)


def test_pushes_toward_the_goal_match_c_mujoco_and_the_maps_index(robot, plan_map):
    """`pushmap.push_pairs` on the tunnel (hard scenario 2) against a reference computed
    here with C MuJoCo's kinematics (each table-checked capsule's ends from its geom's pose):
    for a sample of the edges whose start is clear of the wall and roof, the same (cell, edge)
    pairs; every pair is one of the map's spatial index (built apart, with the map); a wider
    angle only adds pairs; the planner's weighted score at least the path length, kept with
    the map."""
    from lmjx.mapfile.pushmap import far_objects, push_counts, push_pairs
    from lmjx.planner.scoring import table_bounds
    from lmjx.sim.goalfield import GoalField

    m = load_map(plan_map)
    b, reach = m.edges, m.reach
    sc = scenario(2, tasks="hard")
    field = GoalField(sc, *table_bounds(robot))
    cells, edges = push_pairs(robot, m.failure, b, reach, sc, field)
    assert len(cells) > 100
    ny, nx = reach.labels.shape
    index = {(c, int(e)) for c in range(ny * nx) for e in b.index_edges[b.index_offset[c] : b.index_offset[c + 1]]}
    assert {(int(c), int(e)) for c, e in zip(cells, edges, strict=True)} <= index
    wide_cells, wide_edges = push_pairs(robot, m.failure, b, reach, sc, field, max_angle=90.0)
    ours_45 = set(zip(cells.tolist(), edges.tolist(), strict=True))
    assert ours_45 < set(zip(wide_cells.tolist(), wide_edges.tolist(), strict=True))
    counts = push_counts(cells, reach)
    assert counts.shape == (ny, nx) and counts.sum() == len(cells) and counts.max() > 1
    # the planner's score with a push weight: every metre costs at least 1, more where few push
    from lmjx.planner.scoring import _score_field

    weighted = _score_field(robot, m.failure, reach, b, sc, PlannerConfig(push_weight=1.0))
    assert weighted is _score_field(robot, m.failure, reach, b, sc, PlannerConfig(push_weight=1.0))  # kept
    pts = np.random.default_rng(1).uniform([0.2, 0.0], [0.7, 0.5], (300, 2))
    assert np.all(weighted(pts) >= field(pts) - 1e-9) and np.any(weighted(pts) > 1.5 * field(pts))

    # the reference: C MuJoCo's capsule geoms, the scene's slacks for the wall and roof
    tp = TransitPlanner(robot, m.failure, batched=True)
    tp.set_scene(sc, far_objects(sc), acting=False)
    fixed = ~tp.scene.movable
    clear = np.nonzero(tp.scene_slacks(b.q_start.astype(np.float64))[:, fixed].min(axis=1) >= 0)[0]
    sample = np.random.default_rng(0).choice(clear, 150, replace=False)
    mj, d = robot.mj, mujoco.MjData(robot.mj)
    geom_of_cap = [g for g in range(mj.ngeom) if mj.geom_bodyid[g] != 0]
    caps = [geom_of_cap[c] for c in robot.arm.table_caps]
    gy, gx = np.gradient(field.values, field.cell)
    cell = reach.config.cell
    x0, y0 = reach.xs[0] - cell / 2, reach.ys[0] - cell / 2
    ref = set()
    for e in sample:
        q = b.edge(int(e), ("q",))["q"].astype(np.float64)
        within = tp.scene_slacks(q)[:, fixed].min(axis=1) < 0  # within the wall's or roof's margin
        prefix = int(np.argmax(within)) if within.any() else len(q)
        if prefix < MIN_EDGE_STATES:  # never offered: pushes nothing
            continue
        low = np.zeros((len(q), len(caps), 3))
        for k, qk in enumerate(q):
            d.qpos[:] = qk
            mujoco.mj_kinematics(mj, d)
            for j, g in enumerate(caps):
                axis = d.geom_xmat[g].reshape(3, 3)[:, 2] * mj.geom_size[g, 1]
                ends = (d.geom_xpos[g] - axis, d.geom_xpos[g] + axis)
                low[k, j] = min(ends, key=lambda p: p[2])
        radius = np.array([mj.geom_size[g, 0] for g in caps])
        for k in range(prefix - 1):
            for j in range(len(caps)):
                if low[k, j, 2] - robot.arm.table_z - radius[j] > 0.05:
                    continue
                p, v = low[k, j, :2], low[k + 1, j, :2] - low[k, j, :2]
                fx = int(np.clip(np.floor((p[0] - field.lo[0]) / field.cell), 0, field.shape[1] - 1))
                fy = int(np.clip(np.floor((p[1] - field.lo[1]) / field.cell), 0, field.shape[0] - 1))
                g = -np.array([gx[fy, fx], gy[fy, fx]])
                if np.hypot(*v) > 1e-4 and v @ g >= np.cos(np.radians(45.0)) * np.hypot(*v) * np.hypot(*g) > 0:
                    cx, cy = int(np.floor((p[0] - x0) / cell)), int(np.floor((p[1] - y0) / cell))
                    if 0 <= cx < nx and 0 <= cy < ny:
                        ref.add((cy * nx + cx, int(e)))
    ours = {(int(c), int(e)) for c, e in zip(cells, edges, strict=True) if e in set(sample.tolist())}
    assert len(ref) > 20
    # float32 kinematics against float64: a point on a cell's border may fall either side
    assert len(ours ^ ref) <= max(2, len(ref) // 100), (len(ours), len(ref), sorted(ours ^ ref)[:5])


def test_push_counts_are_kept_in_the_cache_and_read_back(robot, plan_map, tmp_path, monkeypatch):
    """The planner's push counts of a map that does not store them (`pushmap.cached_counts`):
    computed once (the counts `push_pairs` gives), then read from the cache folder by another
    process's bundle without computing, the same weighted score; another scenario, other
    edges, another robot model or goal field is another file; a damaged file or one of
    another shape is computed again and replaced; the cache off: no file."""
    import dataclasses

    from lmjx.mapfile import pushmap
    from lmjx.planner.scoring import _score_field, table_bounds
    from lmjx.sim.goalfield import GoalField

    monkeypatch.setenv("LMJX_CACHE_DIR", str(tmp_path))
    m = load_map(plan_map)
    b, reach = m.edges, m.reach
    b.push = {}  # (the map's own counts: tests/test_pushfield.py)
    sc = scenario(2, tasks="hard")
    field = GoalField(sc, *table_bounds(robot))
    key = pushmap.counts_key(robot, b, reach, sc, field)
    path = tmp_path / "pushes" / f"{key}.npy"
    real = pushmap.scenario_counts
    computed = []  # the planner's scenario_counts calls: (arguments, result)

    def spy(*args, **kwargs):
        computed.append((args, kwargs, real(*args, **kwargs)))
        return computed[-1][2]

    monkeypatch.setattr(pushmap, "scenario_counts", spy)
    weighted = _score_field(robot, m.failure, reach, b, sc, PlannerConfig(push_weight=1.0))
    assert len(computed) == 1  # computed once, for this map, scenario, goal field and the default settings
    args, kwargs, counts = computed[0]
    assert args[2] is b and args[4] == sc and np.array_equal(args[5].values, field.values)
    assert len(args) == 6 and set(kwargs) <= {"progress"}
    cells, _ = pushmap.push_pairs(robot, m.failure, b, reach, sc, field)
    assert np.array_equal(counts, pushmap.push_counts(cells, reach))
    assert path.exists() and np.array_equal(np.load(path), counts) and counts.sum() > 100

    def computing(*args, **kwargs):
        raise AssertionError("computed again")

    monkeypatch.setattr(pushmap, "scenario_counts", computing)
    fresh = load_map(plan_map).edges  # another bundle: nothing memoized on it
    fresh.push = {}
    again = _score_field(robot, m.failure, reach, fresh, sc, PlannerConfig(push_weight=1.0))
    pts = np.random.default_rng(2).uniform([0.2, 0.0], [0.7, 0.5], (200, 2))
    assert again is not weighted and np.array_equal(again(pts), weighted(pts))
    other_edges = dataclasses.replace(b, q_start=b.q_start + np.float32(1e-3))
    other_model = dataclasses.replace(robot, model_hash="0" * 64)
    doubled = GoalField(sc, *table_bounds(robot), weights=lambda p: np.full(len(p), 2.0))
    for k in (
        pushmap.counts_key(robot, b, reach, scenario(3, tasks="hard"), field),
        pushmap.counts_key(robot, other_edges, reach, sc, field),
        pushmap.counts_key(other_model, b, reach, sc, field),
        pushmap.counts_key(robot, b, reach, sc, doubled),
    ):
        assert k != key
    monkeypatch.setattr(pushmap, "scenario_counts", real)
    for damage in (b"not an array", None):
        if damage is None:
            np.save(path, np.zeros((3, 3), np.int64))  # counts of another grid
        else:
            path.write_bytes(damage)
        fixed, where = pushmap.cached_counts(key, counts.shape, lambda: counts)
        assert where == path and np.array_equal(fixed, counts) and np.array_equal(np.load(path), counts)
    monkeypatch.setenv("LMJX_CACHE_DIR", "off")
    assert pushmap.cached_counts(key, counts.shape, lambda: counts)[1] is None


def test_a_report_says_the_settings_its_trials_ran_with():
    """A report rewritten from merged runs (a config that does not know their settings) takes
    the settings from the trials' records: one line where they agree, one per set where not."""
    from lmjx.evaluation.evaluate import EvalConfig, _settings_lines

    config = EvalConfig(tasks="hard", planner=PlannerConfig(push_weight=0.0))
    weighted = PlannerConfig(push_weight=1.0).settings()
    assert PlannerConfig().settings() == weighted  # (the default)
    one = _settings_lines([{"asm": "greedy", "asm_settings": weighted}] * 2, config)
    assert one == [_settings_lines([], EvalConfig(tasks="hard", planner=PlannerConfig(push_weight=1.0)))[0]]
    assert "push_weight 1.0" in one[0]
    plain = PlannerConfig(push_weight=0.0).settings()
    two = _settings_lines([{"asm": "greedy", "asm_settings": weighted}, {"asm": "lazy", "asm_settings": plain}], config)
    assert len(two) == 2 and two[0].startswith("ASM settings (greedy)") and "push_weight 0.0" in two[1]


def test_the_planner_can_simulate_the_robots_own_servos(robot, small_map):
    """`--servo robot`: the planner's simulator tracks joint targets with the robot's own servo
    gains and torque limits.  Against the "real" world's physics with its per-trial draws set
    to nominal (frictions, masses, capsules: what the planner cannot know) and only its servos
    and table contacts left, the planner's "robot" servo predicts where each push leaves the
    target to a micrometre, and playback (the default) does not."""
    from dataclasses import replace

    from lmjx.bench.planner import candidate_actions
    from lmjx.planner.trial import make_simulator

    _mf, sc, _scene, objects, tp, acts = candidate_actions(robot, str(small_map), 3, 6, 0, planner_scene=False)
    drawn = real_physics(robot, len(sc.movable), np.random.default_rng(0))
    servos_only = replace(drawn, friction_scale=(), mass_scale=(), table_friction_scale=1.0, robot_radius_offset=0.0)
    real = CpuSimulator(build_scene(robot, sc, servos_only), threads=1).simulate(tp.park, objects, acts)[:, 0, :2]
    ends = {}
    for servo in ("robot", "playback"):
        sim = make_simulator(robot, resolve_task(3, robot, "hard"), "cpu", servo=servo)
        ends[servo] = np.hypot(*(sim.simulate(tp.park, objects, acts)[:, 0, :2] - real).T)
    moved = np.hypot(*(real - objects[0, :2]).T)
    assert moved.max() > 0.01, moved  # the actions push the target
    assert ends["robot"].max() < 1e-6, ends["robot"]
    assert ends["playback"].max() > 1e-3, ends["playback"]  # the servos matter to where a push ends
    assert PlannerConfig(servo="robot").settings("greedy")["servo"] == "robot"
    assert "servo" not in PlannerConfig(servo="robot").settings("random")
    assert "servo" not in PlannerConfig(servo="playback").settings() and PlannerConfig().servo == "robot"
    with pytest.raises(Exception, match="unknown servo model 'stiff'"):
        PlannerConfig(servo="stiff").validate()


class _CountingSimulator:
    """A simulator passing every request on, counting the control points of the actions it is
    given (each action once per start): an account of the planner's simulations kept apart from
    the planner's own."""

    def __init__(self, sim) -> None:
        self.sim, self.name, self.prefers_batches, self.steps_run = sim, sim.name, sim.prefers_batches, 0
        self.counted = 0

    @property
    def description(self) -> str:
        return self.sim.description

    def simulate(self, robot_q, objects, actions):
        self.counted += sum(len(a.q) for a in actions)
        return self.sim.simulate(robot_q, objects, actions)

    def simulate_many(self, requests):
        return [self.simulate(*r) for r in requests]


def test_the_planning_limit_counts_simulated_control_steps(robot, plan_map):
    """The planning limit (`max_sim_steps`) counts the control steps the planner simulated,
    not seconds: the trial's count is the simulator's own account, and a trial stops before
    the decision that would follow the limit's being reached (the second here: a limit of the
    first decision's steps), ending "planning limit", a failure; one more step lets it go on.
    Wall-clock planning time is recorded and stops nothing."""
    from dataclasses import replace

    from lmjx.planner.trial import make_simulator

    m = load_map(plan_map, robot=robot)
    task = resolve_task(1, robot, "hard")
    sim = make_simulator(robot, task, "cpu")
    # (no push weight: its counts are not needed; rescoring on: its redrawn starts count too)
    cfg = PlannerConfig(asm="greedy", greedy_candidates=4, rescore_top=2, rescore_draws=2, max_actions=2,
                        push_weight=0.0)  # fmt: skip

    def trial(limit: int):
        counting = _CountingSimulator(sim)
        res = run_trial(setup_trial(robot, m, task, replace(cfg, max_sim_steps=limit), 401000, counting))
        return res, counting.counted

    free, counted = trial(10**9)
    first = free.steps[0].sim_steps
    assert free.stopped == "budget" and free.actions == 2 and free.planning_s > 0.0, free
    assert free.sim_steps == counted == sum(s.sim_steps for s in free.steps) > first > 0
    stopped, counted = trial(first)
    assert (stopped.stopped, stopped.reason, stopped.success, stopped.actions) == ("planning limit",) * 2 + (False, 1)
    assert stopped.sim_steps == counted == first and stopped.summary()["end"] == "planning limit"
    assert "planning limit" in ENDS and trial(first + 1)[0].sim_steps == free.sim_steps


def test_the_real_world_steps_unwatched_as_watched(robot, plan_map):
    """The "real" world steps an action's edge and settling in `mujoco.rollout` unless
    something watches every step (a recorder): the same world to the bit, the solver's warm
    start and the last step's contacts included, action after action."""
    m = load_map(plan_map)
    task = resolve_task(1, robot, "paper")
    setup = setup_trial(robot, m, task, PlannerConfig(asm="random"), seed=3)
    obs = setup.world.reset(setup.layout, setup.planner.transits.park)
    setup.planner.transits.set_scene(task.scenario, obs.objects)
    acts = setup.planner.transits.actions(m.edges, np.arange(m.edges.n_edges), obs.robot_q, 3)
    assert len(acts) == 3
    seen = []
    for watched in (True, False):
        world = SimulatedRealWorld(robot, 3)
        world.reset(setup.layout, setup.planner.transits.park)
        if watched:
            world.on_step = lambda m_, d_: None
        runs = []
        for a in acts:
            o = world.execute(a)
            d = world.data
            runs.append((o.objects, o.transit_contacts, o.transit_left, d.qpos, d.qvel, d.qacc_warmstart, d.time,
                         d.contact.geom, d.ncon))  # fmt: skip
            runs[-1] = tuple(np.array(x, copy=True) if isinstance(x, np.ndarray) else x for x in runs[-1])
        seen.append(runs)
    for a, b in zip(*seen, strict=True):
        for x, y in zip(a, b, strict=True):
            assert np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y
