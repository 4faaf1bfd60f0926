"""Scenarios, the simulated "real" world, actions and the planner (Algorithm 3)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import cli

from lmjx.evaluation.results import trials_of
from lmjx.mapfile.read import load_map
from lmjx.model.failure import parse_failure
from lmjx.planner.clearance import park_pose
from lmjx.planner.records import ENDS
from lmjx.planner.scoring import score
from lmjx.planner.transit import TransitPlanner
from lmjx.planner.trial import run_trial, setup_trial
from lmjx.sim.controls import controls
from lmjx.sim.cpu import CpuSimulator
from lmjx.sim.realworld import LEAVE_CLEAR, SimulatedRealWorld, TransitContacts, real_physics
from lmjx.sim.scenarios import in_goal, resolve_task, sample_layout, scenario
from lmjx.sim.scene import build_scene, object_qpos, read_objects, set_state
from lmjx.sim.sceneboxes import MIN_EDGE_STATES, OBJECT_MARGIN
from lmjx.types import CONTROL_DT, PlannerConfig


@pytest.mark.parametrize("n", [1, 2, 3])
def test_layouts_are_seeded_and_apart(robot, n):
    sc = scenario(n, tasks="hard")
    a, b, c = sample_layout(sc, 5), sample_layout(sc, 5), sample_layout(sc, 6)
    assert np.array_equal(a.poses, b.poses) and not np.array_equal(a.poses, c.poses)
    assert len(a.poses) == {1: 4, 2: 1, 3: 12}[n]
    nominal = np.array([[o.x, o.y, o.yaw] for o in sc.movable])
    assert np.all(np.abs(a.poses[:, :2] - nominal[:, :2]) <= sc.jitter + 1e-12)
    # at rest in the scene: nothing moves, nothing overlaps
    s = build_scene(robot, sc)
    d = mujoco.MjData(s.model)
    set_state(s, d, park_pose(robot, parse_failure("case2", robot)), object_qpos(s, a.poses))
    for _ in range(400):
        mujoco.mj_step(s.model, d)
    assert np.abs(read_objects(s, d)[:, :3] - object_qpos(s, a.poses)[:, :3]).max() < 1e-3
    assert not in_goal(sc, a.poses[0, :2])


def test_a_transit_counts_what_it_touches_not_the_chatter_of_what_it_leaves():
    # the arm ends a push against the target; as it slides off, the contact comes and goes
    # while the arm is still within LEAVE_CLEAR of it: the same contact, being left
    c = TransitContacts({"target"}, set())
    timeline = [{"target"}, set(), set(), {"target"}, set(), {"target"}] + [set()] * 30 + [{"target"}, {"obstacle1"}]
    for objects in timeline:
        c.update(objects, set())
    assert c.left == {"target"} and c.objects == {"obstacle1"} and not c.fixed and c.leaving == {"target"}
    # once the arm has been LEAVE_CLEAR clear of the target, touching it again counts
    c = TransitContacts({"target"}, set())
    c.update({"target"}, set())
    c.update(set(), set(), {"target"})
    assert not c.leaving and not c.objects
    c.update(set(), set())
    c.update({"target"}, set())
    assert c.objects == {"target"}
    # a fixed obstacle met during the transit is a hit; nothing touched before is a contact
    c = TransitContacts(set(), set())
    c.update(set(), {"wall_near"})
    c.update({"target"}, {"wall_near"})
    assert c.fixed == {"wall_near"} and c.objects == {"target"} and c.left == set()


def test_the_real_world_tells_when_the_arm_is_clear_of_an_object(robot):
    """`SimulatedRealWorld._clear_of` against C MuJoCo's distances: clear at LEAVE_CLEAR and
    beyond, not nearer (the arm's contact geoms against the object's box)."""
    sc = scenario(1, tasks="hard")
    lay = sample_layout(sc, 1)
    w = SimulatedRealWorld(robot, 1)
    w.reset(lay, park_pose(robot, parse_failure("case2", robot)))
    m, d = w.scene.model, w.data
    box = w._geoms_of["target"][0]

    def gap() -> float:
        return min(mujoco.mj_geomDistance(m, d, int(a), box, 1.0, None) for a in w._arm_geoms)

    assert gap() > LEAVE_CLEAR and w._clear_of({"target"}) == {"target"}
    jnt = m.body("target").jntadr[0]
    adr = m.jnt_qposadr[jnt]
    start, hand = d.qpos[adr : adr + 3].copy(), d.xpos[m.body("hand").id].copy()
    near = 0
    for shift in np.linspace(0.0, 1.0, 4001):  # slide the target toward the hand (0.3 mm steps)
        d.qpos[adr : adr + 3] = (1 - shift) * start + shift * hand
        mujoco.mj_forward(m, d)
        g = gap()
        assert (w._clear_of({"target"}) == {"target"}) == (g >= LEAVE_CLEAR), g
        near += 0 <= g < LEAVE_CLEAR
        if g < 0:
            break
    assert g < 0 and near >= 2  # it passed through the band where it is not yet clear


def test_real_world_differs_from_the_planners_within_documented_ranges(robot):
    rng = np.random.default_rng(3)
    p = real_physics(robot, 4, rng)
    assert all(0.7 <= f <= 1.3 for f in p.friction_scale) and all(0.8 <= m <= 1.25 for m in p.mass_scale)
    assert -0.003 <= p.robot_radius_offset <= 0.003 and p.servo_force == tuple(robot.tau_max)
    sc = scenario(1, tasks="hard")
    lay = sample_layout(sc, 1)
    w1, w2 = SimulatedRealWorld(robot, 1), SimulatedRealWorld(robot, 1)
    q = park_pose(robot, parse_failure("case2", robot))
    o1, o2 = w1.reset(lay, q), w2.reset(lay, q)
    assert np.array_equal(o1.objects, o2.objects)  # seeded: the same noise
    err = o1.objects[:, :2] - w1.truth()[:, :2]
    assert 0 < np.abs(err).max() < 0.01  # observed with noise
    assert w1.scene.model.geom("target_geom").friction[0] != pytest.approx(0.5)  # perturbed


def test_controls_follow_the_action(robot, small_map):
    m = load_map(small_map)
    tp = TransitPlanner(robot, m.failure)
    a = None
    for e in range(m.edges.n_edges):
        a = tp.action(m.edges, e, tp.park)
        if a is not None:
            break
    assert a is not None
    assert np.allclose(a.q[a.transit_steps :], m.edges.edge(a.edge)["q"])
    u = controls(a, 0.005, 0.5)
    assert len(u) == len(a.q) * round(CONTROL_DT / 0.005) + 100
    np.testing.assert_allclose(u[round(CONTROL_DT / 0.005) - 1, :7], a.q[0], atol=1e-12)
    np.testing.assert_allclose(u[-1, :7], a.q[-1])
    # the planner's servos play the action back closely (objects moved out of the way)
    sc = scenario(1, tasks="hard")
    s = build_scene(robot, sc)
    d = mujoco.MjData(s.model)
    far = np.array([[1.0, -0.9 + 0.1 * i, 0.0] for i in range(len(sc.movable))])
    set_state(s, d, tp.park, object_qpos(s, far))
    worst = 0.0
    sub = round(CONTROL_DT / 0.005)
    for k, ui in enumerate(u[: len(a.q) * sub]):
        d.ctrl[:] = ui
        mujoco.mj_step(s.model, d)
        if (k + 1) % sub == 0:
            worst = max(worst, np.abs(d.qpos[s.robot_qpos] - a.q[(k + 1) // sub - 1]).max())
    assert worst < 0.02  # rad; largest where the transit's velocity meets the edge's


def test_batched_simulation_equals_one_by_one(robot, small_map):
    m = load_map(small_map)
    tp = TransitPlanner(robot, m.failure)
    acts = [a for a in (tp.action(m.edges, e, tp.park) for e in range(0, 60, 3)) if a is not None][:6]
    sc = scenario(1, tasks="hard")
    s = build_scene(robot, sc)
    sim = CpuSimulator(s)
    objs = object_qpos(s, sample_layout(sc, 2).poses)
    batch = sim.simulate(tp.park, objs, acts)
    single = np.concatenate([sim.simulate(tp.park, objs, [a]) for a in acts])
    # each action's result is taken where it ends, whatever else shares the batch
    np.testing.assert_array_equal(batch, single)
    assert batch.shape == (len(acts), 4, 7)
    assert np.all(score(sc, robot, batch) < 1.0)  # nobody fell off the table


GOLDEN = json.loads((Path(__file__).parent / "data" / "panda_golden.json").read_text())


def test_panda_map_is_unchanged_by_the_robot_generalisation(small_map):
    """The small case-2 map (the arguments of tests/golden.py) holds what the code made
    before lmjx took any robot: the same reach labels, the same edges and rejections."""
    from golden import MAP_ARGS, map_figures

    assert MAP_ARGS == ("--failure", "case2", "--edges", "3000", "--cell", "0.05", "--seed", "1")
    got, want = map_figures(str(small_map)), GOLDEN["map"]
    for k in ("areas", "labels", "edges_valid", "edges_sampled", "states"):
        assert got[k] == want[k], k
    # One start IK of the 3,000 lies on a float32 knife edge that XLA's CPU code (which differs
    # with the CPU's instruction set: AVX2, AVX-512) tips either way: found (then the edge hits
    # the table) or not.  Every other rejection, and every valid edge, must be the same.
    rej, rej_want = got["rejected"], want["rejected"]
    assert set(rej) == set(rej_want) and sum(rej.values()) == sum(rej_want.values())
    moved = {r: rej[r] - rej_want[r] for r in rej if rej[r] != rej_want[r]}
    assert moved in ({}, {"ik": 1, "table_collision": -1}), moved
    for k in ("q_sum", "q_abs_sum"):
        assert got[k] == pytest.approx(want[k], rel=1e-6), k


@pytest.mark.parametrize("asm", ["random", "lazy", "greedy"])
def test_trials_run_and_repeat(robot, plan_map, asm):
    m = load_map(plan_map)
    # (the golden trials' settings: no push weight, so the score below is the path length; no
    # rescoring; the playback servos; the map's edges alone)
    cfg = PlannerConfig(asm=asm, max_actions=2, greedy_candidates=8, lazy_tries=4, push_weight=0.0, rescore_top=0,
                        servo="playback", turn_edges=False)  # fmt: skip
    a = run_trial(setup_trial(robot, m, resolve_task(1, robot, "hard"), cfg, seed=3))
    b = run_trial(setup_trial(robot, m, resolve_task(1, robot, "hard"), cfg, seed=3))
    wall = {"planning_s": 0, "compile_s": 0}  # the first run compiles what the second finds compiled
    assert a.summary() | wall == b.summary() | wall
    assert 1 <= a.actions <= 2 and a.execution_s > 0
    # the Panda plans as it did when the golden trials were written (tests/golden.py)
    want = GOLDEN["trials"][asm]
    assert (a.success, a.actions, [s.edge for s in a.steps]) == (want["success"], want["actions"], want["edges"])
    # (2 um apart between CPUs with and without AVX-512: the observation and transit programs
    # run in XLA's CPU code; the "real" world is C MuJoCo)
    assert a.final_distance == pytest.approx(want["final_distance_m"], abs=2e-5)
    assert a.execution_s == pytest.approx(want["execution_s"], abs=1e-6)
    # what the planner expected of its pick (Greedy, Lazy; Random simulates nothing) and its
    # score of what came, against the truth: scenario 1 has nothing fixed between the target
    # and the goal (the path length is the straight distance), the last observation is 2 mm
    # noisy, the goal field a 5 mm grid
    done = [s for s in a.steps if s.edge >= 0]  # (a last record may be a decision that found no action)
    assert all((s.predicted_distance is None) == (asm == "random") for s in done)
    assert done[-1].score_after == pytest.approx(a.final_distance, abs=0.008)
    sims = [s.simulated for s in a.steps]
    if asm == "random":
        assert sims == [0] * len(sims)
    elif asm == "lazy":
        assert all(1 <= n <= 4 for n in sims)
    else:  # its 8 candidates, or every feasible action where fewer are (this small map)
        assert all(1 <= n <= 8 for n in sims)


def test_plan_and_evaluate_cli(small_map, tmp_path):
    r = cli("plan", "--map", small_map, "--scenario", "2", "--asm", "greedy", "--candidates", "8",
            "--max-actions", "2", "--json").ok()  # fmt: skip
    out = json.loads(r.stdout)
    assert {"success", "actions", "planning_s", "execution_s", "end", "asm_settings", "steps"} <= set(out)
    assert out["asm_settings"]["futile_filter"] is True and out["tasks"] == "paper"
    assert out["asm_settings"]["push_weight"] == 1.0  # the default (0 with the paper's settings, below)
    assert out["asm_settings"]["rescore"] == "best 8, 8 starts"  # the default (off with the paper's settings)
    paper = json.loads(cli("plan", "--map", small_map, "--scenario", "2", "--asm", "lazy", "--asm-settings", "paper",
                           "--when-stuck", "options", "--late-start", "--max-actions", "1",
                           "--json").ok().stdout)  # fmt: skip
    want = {"futile_filter": False, "path_score": False, "lazy_fallback": False, "lazy_tries": None,
            "greedy_subset": "0.25 of the edges over the target", "when_stuck": "options",
            "late_start": True, "turn_edges": False, "push_weight": 0.0, "servo": "robot"}  # fmt: skip
    assert out["asm_settings"]["when_stuck"] == "best" and out["asm_settings"]["late_start"] is False
    assert out["asm_settings"]["servo"] == "robot"  # the default (the ASMs' settings keep it)
    assert paper["asm_settings"] == want
    for args, message in (
        (("plan", "--map", small_map, "--scenario", "1", "--asm", "greedy", "--failure", "case1"), "not case1"),
        (("plan", "--map", tmp_path / "none.h5", "--scenario", "1", "--asm", "lazy"), "does not exist"),
        (("plan", "--map", small_map, "--scenario", "4", "--asm", "lazy"), "invalid choice"),
        (("plan", "--map", small_map, "--scenario", "1", "--asm", "clever"), "invalid choice"),
        (("evaluate", "--maps", tmp_path, "--out", tmp_path / "e"), "does not exist"),
        (("evaluate", "--asms", "smart", "--out", tmp_path / "e"), "unknown ASM"),
        (
            (
                "plan",
                "--map",
                small_map,
                "--scenario",
                "2",
                "--asm",
                "greedy",
                "--asm-settings",
                "paper",
                "--push-weight",
                "1",
            ),
            "leave out --push-weight",
        ),
        (("plan", "--map", small_map, "--scenario", "2", "--asm", "greedy", "--push-weight", "-1"), "at least 0"),
    ):
        cli(*args).one_line_error(message)
    assert not (tmp_path / "e").exists()  # a refused evaluation leaves no empty --out folder behind
    maps = tmp_path / "maps"
    maps.mkdir()
    (maps / "case2.h5").write_bytes(small_map.read_bytes())
    ev = tmp_path / "eval"
    args = ("evaluate", "--failures", "case2", "--scenarios", "1", "--asms", "random,greedy", "--trials", "2",
            "--max-actions", "2", "--candidates", "4", "--maps", maps, "--out", ev,
            "--set", "push_weight=0")  # fmt: skip
    cli(*args).ok()
    records = trials_of(ev / "results.json")
    assert len(records) == 4
    assert set(records[0]) >= {"failure", "scenario", "asm", "seed", "success", "actions", "planning_s", "execution_s",
                               "end", "asm_settings", "steps"}  # fmt: skip
    assert all(r["end"] in ENDS for r in records) and {r["tasks"] for r in records} == {"paper"}
    for r in records:
        for step in r["steps"]:
            assert {"target_moved_m", "transit_contacts", "transit_hit_fixed", "transit_left"} <= set(step)
            assert not step["transit_hit_fixed"]
            # what the planner expected (Greedy: its pick's simulated outcome; Random simulates
            # nothing) and its score of what came: in scenario 1 nothing fixed stands between
            # the target and the goal, so the path length (no push weight) is the straight
            # distance (5 mm grid)
            assert (step["predicted_score_m"] is None) == (r["asm"] == "random")
            assert step["score_after_m"] == pytest.approx(step["distance_after_m"], abs=0.005)
    assert "How the trials ended" in (ev / "report.md").read_text()
    assert (ev / "report.md").exists() and (ev / "bubble.png").exists() and (ev / "actions.png").exists()
    r = cli(*args)  # resumes: nothing left to do
    assert r.returncode == 0 and len(trials_of(ev / "results.json")) == 4
    # one task set per folder
    cli(*args, "--asms", "random", "--tasks", "hard").one_line_error("task set (there paper ")
    # the same trials face the same layouts whatever the ASM
    assert sorted({x["seed"] for x in records if x["asm"] == "random"}) == sorted(
        {x["seed"] for x in records if x["asm"] == "greedy"}
    )


def test_scenarios_command_draws_without_opengl(tmp_path):
    # CI has no display and no OSMesa: the diagrams must still come (a process of its own,
    # started without any OpenGL setting)
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "PYOPENGL_PLATFORM")}
    r = subprocess.run([sys.executable, "-m", "lmjx.cli", "scenarios", "--out", str(tmp_path)], env=env,
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    for n in (1, 2, 3):
        data = (tmp_path / f"scenario{n}.png").read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
        assert f"scenario {n} (paper tasks" in r.stdout
    bad = cli("scenarios", "--out", "/proc/nope")
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1, bad.stderr


def test_batched_transits_equal_c_mujoco_transits(robot, small_map):
    """The clearance kernel's transits (used with a GPU simulator) are C MuJoCo's: the same
    feasible edges, the same joint targets, from the park pose and from where edges end;
    some straight transits collide (they go via the park pose or the roadmap)."""
    m = load_map(small_map)
    one = TransitPlanner(robot, m.failure)
    batch = TransitPlanner(robot, m.failure, batched=True)
    rng = np.random.default_rng(4)
    edges = rng.permutation(m.edges.n_edges)[:120]
    ends = rng.permutation(m.edges.n_edges)[:2]
    starts = [one.park] + [m.edges.edge(int(e))["q"][-1].astype(np.float64) for e in ends]
    feasible, routes = 0, []
    for q in starts:
        a = one.actions(m.edges, edges, q, len(edges))
        b = batch.actions(m.edges, edges, q, len(edges))
        assert [x.edge for x in a] == [x.edge for x in b]
        for x, y in zip(a, b, strict=True):
            assert np.array_equal(x.q, y.q) and np.array_equal(x.qd, y.qd) and x.route == y.route
        feasible += len(a)
        routes += [x.route for x in a]
    assert feasible > 0 and routes.count("direct") < len(routes)  # some straight transits collide
    # asking for fewer gives the first ones, in order
    first = one.actions(m.edges, edges, one.park, 5)
    assert [x.edge for x in batch.actions(m.edges, edges, one.park, 5)] == [x.edge for x in first]


def test_lockstep_trials_equal_trials_run_alone(robot, plan_map):
    """Trials run together (lmjx.evaluation.lockstep, as lmjx evaluate runs them: each trial on a
    thread of its own with its own TransitPlanner and layout) decide as they do alone.  Lazy on
    the CPU builds its tries one at a time, waiting for each simulation while the other trials
    compute: each try must still be checked against its own trial's scene."""
    from lmjx.evaluation.lockstep import run_lockstep
    from lmjx.planner.transit import TransitPlanner
    from lmjx.planner.trial import make_simulator

    m = load_map(plan_map)
    sim = make_simulator(robot, resolve_task(1, robot, "hard"), "cpu")
    runs = [("random", 5), ("lazy", 6), ("lazy", 8), ("greedy", 7)]
    cfgs = [PlannerConfig(asm=a, max_actions=1, greedy_candidates=6, lazy_tries=4, lazy_cap=True) for a, _ in runs]

    def record(res) -> dict:  # the trial and each of its actions, wall times (planning, compiling) left out
        wall = {"planning_s": 0, "compile_s": 0}
        times = wall | {"latency_s": 0, "phase_s": 0, "shared_s": 0}
        return res.summary() | wall | {"steps": [s | times for s in res.action_records()]}

    alone = [
        record(run_trial(setup_trial(robot, m, resolve_task(1, robot, "hard"), c, seed=seed, simulator=sim)))
        for c, (_, seed) in zip(cfgs, runs, strict=True)
    ]
    lazy_tries = [x["simulated"] for (a, _), r in zip(runs, alone, strict=True) if a == "lazy" for x in r["steps"]]
    assert max(lazy_tries) > 1  # Lazy waited for a simulation between tries (what could go wrong)
    for window in (None, 2):  # all at once (a GPU's batches), or two in flight (the CPU's cores)
        task = resolve_task(1, robot, "hard")
        setups = [
            setup_trial(robot, m, task, c, seed=seed, simulator=sim, transits=TransitPlanner(robot, m.failure))
            for c, (_, seed) in zip(cfgs, runs, strict=True)
        ]
        together: dict[int, dict] = {}
        events: list[tuple[str, int]] = []

        def logged(i, trial, events=events):
            events.append(("start", i))
            return (yield from trial)

        def done(i, res, together=together, events=events):
            together[i] = record(res)
            events.append(("end", i))

        run_lockstep(
            [(logged(i, s.planner.trial(s.world, s.layout, s.planner_seed)), s.world) for i, s in enumerate(setups)],
            sim,
            done,
            threads=2,
            window=window,
        )
        starts = [events.index(("start", i)) for i in range(len(runs))]
        first_end = min(events.index(("end", i)) for i in range(len(runs)))
        assert (starts[2] > first_end) == (window == 2)  # the third waits for a place
        for i, res in enumerate(alone):
            assert together[i] == res, f"trial {i} ({runs[i][0]}, seed {runs[i][1]}) decided otherwise together"


class _BatchPreferringCpu(CpuSimulator):
    prefers_batches = True


def test_lazy_in_one_batch_chooses_as_lazy_one_by_one(robot, plan_map):
    """With a simulator that prefers batches, Lazy simulates its tries at once and takes the
    first improvement in their order: the same choice as trying them one at a time."""
    from lmjx.planner.edge_planner import Planner
    from lmjx.types import Observation

    m = load_map(plan_map)
    sc = scenario(1, tasks="hard")
    scene = build_scene(robot, sc)
    cfg = PlannerConfig(asm="lazy", lazy_tries=4)
    one = Planner(robot, m.failure, m.reach, m.edges, sc, CpuSimulator(scene), cfg)
    batch = Planner(robot, m.failure, m.reach, m.edges, sc, _BatchPreferringCpu(scene), cfg,
                    transits=one.transits)  # fmt: skip
    chosen = 0
    for seed in range(3):
        obs = Observation(one.transits.park, object_qpos(scene, sample_layout(sc, seed).poses), 0.0)
        a, ra = one.choose(obs, np.random.default_rng(seed))
        b, rb = batch.choose(obs, np.random.default_rng(seed))
        assert (a is None) == (b is None)
        if a is not None:
            assert a.edge == b.edge and ra.predicted_distance == rb.predicted_distance
            assert ra.simulated <= rb.simulated
            chosen += 1
    assert chosen >= 2


def test_redrawn_observations_spread_as_the_cameras_noise():
    """`drawn_starts`: x, y and yaw of each upright object redrawn with the observation noise
    the "real" world's camera has (the executor's figures); everything else kept; an object
    seen off its resting height (fallen: as the executor's observation tells it) kept as seen."""
    from lmjx.planner.scoring import drawn_starts
    from lmjx.types import RESCORE_POS_NOISE, RESCORE_YAW_NOISE

    world = SimulatedRealWorld.__new__(SimulatedRealWorld)
    SimulatedRealWorld.__init__(world, None, 0)  # type: ignore[arg-type]
    assert pytest.approx((world.pos_noise, world.yaw_noise)) == (RESCORE_POS_NOISE, RESCORE_YAW_NOISE)
    objects = np.zeros((3, 7))
    objects[:, :3] = [[0.5, 0.3, 0.025], [0.4, -0.1, 0.03], [0.6, 0.0, 0.01]]
    yaws = np.array([0.3, -3.1, 0.7])
    objects[:, 3], objects[:, 6] = np.cos(yaws / 2), np.sin(yaws / 2)
    resting = np.array([0.025, 0.03, 0.025])  # the third is seen 1.5 cm low: fallen
    draws = drawn_starts(objects, 20_000, np.random.default_rng(3), resting)
    assert draws.shape == (20_000, 3, 7)
    assert np.array_equal(draws[:, 2], np.repeat(objects[None, 2], 20_000, axis=0))
    assert np.allclose(draws[:, :2, 2], objects[:2, 2]) and np.allclose(draws[:, :2, 4:6], 0.0)
    assert np.allclose(np.linalg.norm(draws[..., 3:], axis=-1), 1.0)
    d = draws[:, :2, :2] - objects[None, :2, :2]
    assert np.abs(d.mean(axis=0)).max() < 4 * RESCORE_POS_NOISE / np.sqrt(20_000)
    assert d.std(axis=0) == pytest.approx(np.full((2, 2), RESCORE_POS_NOISE), rel=0.03)
    turned = np.angle(np.exp(1j * (2 * np.arctan2(draws[:, :2, 6], draws[:, :2, 3]) - yaws[None, :2])))
    assert turned.std(axis=0) == pytest.approx([RESCORE_YAW_NOISE] * 2, rel=0.03)  # across -pi as well


def test_greedy_rescores_its_best_candidates_over_redrawn_observations(robot, plan_map):
    """rescore_top: Greedy's best candidates simulated again from redrawn starts; the pick is
    the lowest mean score over the observed start and the draws, as computed here from
    simulations of each start alone; a batching simulator (one request of several starts)
    decides the same; without rescoring the pick is the best of the observed start."""
    from dataclasses import replace

    from lmjx.evaluation.lockstep import _simulate as lockstep_simulate
    from lmjx.planner.edge_planner import Planner, edges_over_target
    from lmjx.planner.scoring import drawn_starts
    from lmjx.types import Observation

    m = load_map(plan_map)
    sc = scenario(1, tasks="hard")
    scene = build_scene(robot, sc)
    sim = CpuSimulator(scene)
    top, draws = 3, 3
    cfg = PlannerConfig(  # the map's own edges: the candidates rebuilt below
        asm="greedy", greedy_candidates=6, rescore_top=top, rescore_draws=draws, turn_edges=False
    )
    planner = Planner(robot, m.failure, m.reach, m.edges, sc, sim, cfg)
    batch = Planner(robot, m.failure, m.reach, m.edges, sc, _BatchPreferringCpu(scene), cfg,
                    transits=planner.transits)  # fmt: skip
    plain = Planner(robot, m.failure, m.reach, m.edges, sc, sim, replace(cfg, rescore_top=0),
                    transits=planner.transits)  # fmt: skip
    checked = 0
    for seed in range(3):
        obs = Observation(planner.transits.park, object_qpos(scene, sample_layout(sc, seed).poses), 0.0)
        planner.draws = np.random.default_rng(seed)
        a, rec = planner.choose(obs, np.random.default_rng(seed))
        if a is None:
            continue
        # the same candidates, simulated here one start at a time
        planner.transits.set_scene(sc, obs.objects)
        edges = edges_over_target(m.edges, m.reach, obs.objects[0, :2], float(sc.target.half[0]), cfg.target_margin)
        acts = planner.transits.actions(m.edges, np.random.default_rng(seed).permutation(edges), obs.robot_q, 6,
                                        None, None)  # fmt: skip
        s = score(sc, robot, sim.simulate(obs.robot_q, obs.objects, acts), planner.field)
        best = np.argsort(s, kind="stable")[:top]
        starts = drawn_starts(obs.objects, draws - 1, np.random.default_rng(seed), [b.zc for b in sc.movable])
        again = [score(sc, robot, sim.simulate(obs.robot_q, o, [acts[i] for i in best]), planner.field) for o in starts]
        mean = (s[best] + np.sum(again, axis=0)) / draws
        assert a.edge == acts[best[np.argmin(mean)]].edge
        assert rec.rescored["mean_m"] == pytest.approx(mean.min(), abs=1e-4)
        assert rec.rescored["changed"] == (best[np.argmin(mean)] != best[0])
        assert rec.summary()["rescored"] == rec.rescored
        batch.draws = np.random.default_rng(seed)  # answered as lmjx.evaluation.lockstep answers a GPU's batches
        steps, answer = batch.decide(obs, np.random.default_rng(seed)), None
        while True:
            try:
                answer = lockstep_simulate(batch.sim, {0: steps.send(answer)})[0]
            except StopIteration as done:
                b = done.value[0]
                break
        assert b.edge == a.edge
        c, crec = plain.choose(obs, np.random.default_rng(seed))
        assert c.edge == acts[best[0]].edge and crec.rescored is None
        checked += 1
    assert checked >= 2

    class Fragile(CpuSimulator):  # the observed start's best push, from any redrawn start, drops the target
        def simulate(self, robot_q, obj_qpos, actions):
            out = super().simulate(robot_q, obj_qpos, actions)
            if not np.array_equal(obj_qpos, observed) and actions and actions[0].edge == nominal:
                out[0, 0, 2] -= 0.5  # below the table: lost
            return out

    obs = Observation(planner.transits.park, object_qpos(scene, sample_layout(sc, 0).poses), 0.0)
    observed = obs.objects
    nominal = plain.choose(obs, np.random.default_rng(0))[0].edge
    fragile = Planner(robot, m.failure, m.reach, m.edges, sc, Fragile(scene), cfg, transits=planner.transits)
    a, rec = fragile.choose(obs, np.random.default_rng(0))
    assert a.edge != nominal and rec.rescored["changed"] and rec.rescored["first_mean_m"] > rec.rescored["mean_m"]
    assert cfg.settings()["rescore"] == "best 3, 3 starts" and "rescore" not in PlannerConfig(rescore_top=0).settings()
    assert PlannerConfig().rescore_top == 8 and PlannerConfig().paper().rescore_top == 0
    assert "rescore" not in PlannerConfig().settings("lazy")  # (Lazy and Random do not rescore)
    with pytest.raises(Exception, match="at least 2 starts"):
        PlannerConfig(rescore_top=4, rescore_draws=1).validate()


def test_simulator_choice_is_said_and_refused_in_one_line(small_map):
    from lmjx.planner.trial import resolve_simulator
    from lmjx.sim.gpu import warp_problem

    if warp_problem() is not None:
        name, why = resolve_simulator("auto")
        assert name == "cpu" and why == warp_problem()
        r = cli("plan", "--map", small_map, "--scenario", "1", "--asm", "greedy", "--sim", "gpu")
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "--sim gpu" in r.stderr, r.stderr
    r = cli("plan", "--map", small_map, "--scenario", "1", "--asm", "greedy", "--candidates", "4", "--max-actions", "1",
            "--json").ok()  # fmt: skip
    out = json.loads(r.stdout)
    assert out["simulator"] in ("cpu", "gpu") and out["simulator_reason"] and out["candidates"] == 4
    assert f"simulator {out['simulator']}" in r.stderr


def arm_clearance_fn(robot, scene, d):
    """clearance(q, geoms): the arm's smallest distance to `geoms` at q, by C MuJoCo's
    mj_geomDistance (the arm's collision capsules; the objects wherever `d` has them)."""
    model = scene.model
    robot_bodies = {robot.mj.body(b).name for b in range(1, robot.mj.nbody)}
    arm = [g for g in range(model.ngeom) if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE
           and model.body(int(model.geom_bodyid[g])).name in robot_bodies and model.geom_contype[g]]  # fmt: skip
    fromto = np.zeros(6)

    def clearance(q, geoms):
        d.qpos[scene.robot_qpos] = q
        mujoco.mj_kinematics(model, d)
        return min((mujoco.mj_geomDistance(model, d, a, g, 1.0, fromto) for a in arm for g in geoms), default=1.0)

    return clearance


@pytest.mark.parametrize("number", [1, 2])
def test_transits_keep_clear_of_the_scene(robot, plan_map, number):
    """Every configuration of every offered transit keeps its margins to the scene, by C
    MuJoCo's mj_geomDistance (movable objects at their observed poses: OBJECT_MARGIN; the
    tunnel: FIXED_MARGIN), the edge's start included; an offered edge's executed states keep
    FIXED_MARGIN from a fixed obstacle too (an edge is cut short before its first state that
    does not, and kept only with MIN_EDGE_STATES states left); edges whose start lies against
    an object are not offered; acting edges act within their executed states."""
    from lmjx.planner.edge_planner import edges_over_target
    from lmjx.planner.transit import ACT_DEPTH
    from lmjx.sim.sceneboxes import FIXED_MARGIN

    m = load_map(plan_map)
    sc = scenario(number, tasks="hard")
    layout = sample_layout(sc, 5)
    scene = build_scene(robot, sc)
    model, d = scene.model, mujoco.MjData(scene.model)
    tp = TransitPlanner(robot, m.failure, batched=True)
    set_state(scene, d, tp.park, object_qpos(scene, layout.poses))
    mujoco.mj_kinematics(model, d)
    objects = read_objects(scene, d)
    tp.set_scene(sc, objects, acting=False)
    edges = edges_over_target(m.edges, m.reach, objects[0, :2], float(sc.target.half[0]), 0.01)
    acts = tp.actions(m.edges, edges, tp.park, len(edges))
    assert 0 < len(acts) < len(edges)
    movable = [model.geom(f"{b.name}_geom").id for b in sc.movable]
    fixed = [model.geom(b.name).id for b in sc.fixed]
    clearance = arm_clearance_fn(robot, scene, d)
    for a in acts:
        for q in a.q[: a.transit_steps]:
            assert clearance(q, movable) >= OBJECT_MARGIN - 1e-4
            assert clearance(q, fixed) >= FIXED_MARGIN - 1e-4
        for q in a.q[a.transit_steps :: 3]:
            assert clearance(q, fixed) >= FIXED_MARGIN - 1e-4
        whole = m.edges.edge(a.edge)["q"]
        assert a.edge_states == len(a.q) - a.transit_steps >= MIN_EDGE_STATES
        np.testing.assert_array_equal(a.q[a.transit_steps :], whole[: a.edge_states])
        if a.edge_states < len(whole):  # cut short exactly where the edge first comes near a fixed obstacle
            assert fixed and clearance(whole[a.edge_states], fixed) < FIXED_MARGIN + 1e-4
            assert clearance(a.q[-1], fixed) >= FIXED_MARGIN - 1e-4
    refused = [int(e) for e in edges if int(e) not in {a.edge for a in acts}]
    starts_against = [e for e in refused if clearance(m.edges.edge(e)["q"][0], movable) < OBJECT_MARGIN]
    assert starts_against  # such edges exist over the target, and none is offered
    # acting: of those, exactly the edges whose arm sweeps ACT_DEPTH into the target's box
    tp.set_scene(sc, objects)
    acting = {a.edge for a in tp.actions(m.edges, edges, tp.park, len(edges))}
    assert acting < {a.edge for a in acts} and (acting or number == 2)  # the tunnel: few, if any, on this map
    for a in acts:
        nearest = min(clearance(q, movable[:1]) for q in a.q[a.transit_steps :])
        assert (nearest <= -ACT_DEPTH + 1e-4) if a.edge in acting else (nearest >= -ACT_DEPTH - 1e-4)


def test_late_starts_enter_an_edge_at_its_first_state_clear_of_the_scene(robot, plan_map):
    """`late_start` (an option, off by default): where the edges with clear starts give fewer
    actions than wanted, an edge over the target whose start lies within FIXED_MARGIN of a
    fixed obstacle (the tunnel's wall or roof) is offered from its first state that keeps
    every margin (C MuJoCo's mj_geomDistance, C MuJoCo's collision
    test for the table and the arm itself), every state before it fails one; the executed part
    is the edge's own states from there, FIXED_MARGIN clear of the fixed obstacles, and the
    transit keeps every margin.  Edges offered without the option are offered alike with it;
    no edge whose start is blocked by a movable object alone is entered late."""
    from lmjx.planner.edge_planner import edges_over_target
    from lmjx.planner.search import LATE_TRIES
    from lmjx.sim.sceneboxes import FIXED_MARGIN

    m = load_map(plan_map)
    sc = scenario(2, tasks="hard")
    scene = build_scene(robot, sc)
    model, d = scene.model, mujoco.MjData(scene.model)
    tp = TransitPlanner(robot, m.failure, batched=True)
    set_state(scene, d, tp.park, object_qpos(scene, sample_layout(sc, 5).poses))
    mujoco.mj_kinematics(model, d)
    objects = read_objects(scene, d)
    tp.set_scene(sc, objects, acting=False)  # (on this small map no late part acts on the target)
    edges = edges_over_target(m.edges, m.reach, objects[0, :2], float(sc.target.half[0]), 0.01)
    plain = tp.actions(m.edges, edges, tp.park, len(edges))
    tp.late_start = True
    acts = tp.actions(m.edges, edges, tp.park, len(edges))
    late = [a for a in acts if a.edge_first > 0]
    assert len(late) >= 10 and len(acts) == len(plain) + len(late)  # 23 of 29 on this map
    same = {a.edge: a for a in acts if a.edge_first == 0}
    assert set(same) == {a.edge for a in plain}
    assert all(np.array_equal(same[a.edge].q, a.q) for a in plain)
    # only where the clear starts fall short, and at most LATE_TRIES edges tried per action missing
    assert [a.edge for a in tp.actions(m.edges, edges, tp.park, len(plain))] == [a.edge for a in plain]
    few = [a.edge for a in tp.actions(m.edges, edges, tp.park, len(plain) + 10) if a.edge_first > 0]
    tried = set(edges[tp.blocked(m.edges.q_start[edges].astype(np.float64))][: LATE_TRIES * 10].tolist())
    assert 0 < len(few) <= 10 and few == [a.edge for a in late if a.edge in tried][:10]
    movable = [model.geom(f"{b.name}_geom").id for b in sc.movable]
    fixed = [model.geom(b.name).id for b in sc.fixed]
    clearance = arm_clearance_fn(robot, scene, d)

    def clear(q, tol: float) -> bool:  # every margin kept, give or take tol (the kernels' float32)
        return (clearance(q, movable) >= OBJECT_MARGIN + tol and clearance(q, fixed) >= FIXED_MARGIN + tol
                and not tp.colliding(q))  # fmt: skip

    for a in late:
        whole = m.edges.edge(a.edge)["q"].astype(np.float64)
        assert clearance(whole[0], fixed) < FIXED_MARGIN + 1e-4  # its own start: in a fixed obstacle's margin
        assert clear(whole[a.edge_first], -1e-4)
        assert not any(clear(q, 1e-4) for q in whole[: a.edge_first])  # the first such state
        assert a.edge_states >= MIN_EDGE_STATES
        np.testing.assert_array_equal(a.q[a.transit_steps :], whole[a.edge_first : a.edge_first + a.edge_states])
        assert all(clearance(q, fixed) >= FIXED_MARGIN - 1e-4 for q in a.q[a.transit_steps :: 3])
        assert all(clear(q, -1e-4) for q in a.q[: a.transit_steps : 2])
