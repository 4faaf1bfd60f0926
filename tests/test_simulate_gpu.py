"""The GPU simulator (MuJoCo Warp) against C MuJoCo, and the two model facts it relies on.

The model facts need only C MuJoCo and run everywhere.  The simulator tests need warp-lang
(requirements-test.lock installs it: `make test` runs them): with no CUDA GPU they run on
Warp's CPU device on short actions, with one on whole actions.  The agreement over 200+ Greedy
decisions (the acceptance test of the GPU simulator) runs only on a CUDA GPU, in the
configuration the evaluation runs (servo model "robot", Greedy's rescoring) and out of sample:
on maps and decision seeds chosen before its first run in that configuration and never used
before (`lmjx.evaluation.agreement.MAP_SEED`, `FIRST_SEED`; benchmarks/RESULTS.md).
"""

from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest

from lmjx.evaluation.agreement import FIRST_SEED, MAP_SEED, SERVO  # chosen before the agreement test's first run
from lmjx.model.failure import parse_failure
from lmjx.planner.clearance import park_pose
from lmjx.sim.cpu import CpuSimulator
from lmjx.sim.gpu import GpuSimConfig, GpuSimulator, warp_problem
from lmjx.sim.scenarios import resolve_task, sample_layout, scenario
from lmjx.sim.scene import build_scene, object_qpos, set_state


def _contacts(m: mujoco.MjModel, d: mujoco.MjData) -> np.ndarray:
    mujoco.mj_forward(m, d)
    c = d.contact[: d.ncon]
    return np.concatenate([c.geom, c.pos, c.frame, c.dist[:, None]], axis=1) if d.ncon else np.zeros((0, 15))


def test_c_mujoco_collides_box_pairs_the_same_with_or_without_native_ccd(robot):
    """The GPU simulator sets mjDSBL_NATIVECCD so that MuJoCo Warp collides boxes with the
    primitive box-box routine; C MuJoCo uses that routine either way (so the flag changes
    nothing in the reference): the same contacts, in states where boxes touch each other,
    the table and the arm."""
    sc = scenario(3, tasks="hard")
    scene = build_scene(robot, sc)
    m = scene.model
    d = mujoco.MjData(m)
    q = park_pose(robot, parse_failure("case2", robot))
    touching = 0
    for seed in range(4):
        objects = object_qpos(scene, sample_layout(sc, seed).poses)
        objects[1, :2] = objects[0, :2] + [0.049, 0.01]  # a box against the target
        objects[2, :3] = objects[0, :3] + [0.0, 0.0, 0.055]  # a box on the target
        set_state(scene, d, q, objects)
        for _ in range(20):
            mujoco.mj_step(scene.model, d)
        with_ccd = _contacts(m, d)
        m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_NATIVECCD
        without = _contacts(m, d)
        m.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_NATIVECCD)
        np.testing.assert_array_equal(with_ccd, without)
        boxes = set(m.geom_bodyid[with_ccd[:, :2].astype(int)].ravel()) & set(scene.obj_body)
        touching += len(boxes)
    assert touching > 8


def test_fused_scene_has_the_same_dynamics(robot):
    """`fuse_static` (the GPU simulator's scene) merges jointless bodies into their parents:
    a shallower tree with the same state layout, mass matrix, bias forces and contacts."""
    sc = scenario(1, tasks="hard")
    a, b = build_scene(robot, sc), build_scene(robot, sc, fuse_static=True)
    assert b.model.nbody < a.model.nbody and a.model.nq == b.model.nq
    assert np.array_equal(a.robot_qpos, b.robot_qpos) and np.array_equal(a.obj_qpos, b.obj_qpos)
    da, db = mujoco.MjData(a.model), mujoco.MjData(b.model)
    rng = np.random.default_rng(0)
    for seed in range(5):
        q = robot.lower + rng.random(robot.nq) * (robot.upper - robot.lower)
        objects = object_qpos(a, sample_layout(sc, seed).poses)
        for s, d in ((a, da), (b, db)):
            set_state(s, d, q, objects)
            d.qvel[:] = np.random.default_rng(seed).normal(0, 0.5, s.model.nv)
            mujoco.mj_forward(s.model, d)
        ma, mb = np.zeros((a.model.nv,) * 2), np.zeros((b.model.nv,) * 2)
        mujoco.mj_fullM(a.model, da, ma)
        mujoco.mj_fullM(b.model, db, mb)
        np.testing.assert_allclose(mb, ma, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(db.qfrc_bias, da.qfrc_bias, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(db.qacc, da.qacc, rtol=1e-6, atol=1e-6)
        assert da.ncon == db.ncon


def test_the_decision_measure_rescores_as_greedy_does(robot, plan_map):
    """The agreement test's measurement in its configuration (Greedy's rescoring `RESCORE`,
    the planner's score), on C MuJoCo where no GPU is: a simulator measured against itself
    agrees exactly (every pick, every target end, the rescored rollouts counted); the stiff
    "playback" servo measured against the "robot" servo it stands in for does not (its target
    ends differ), so the measurement sees what the servo changes."""
    from lmjx.evaluation.agreement import RESCORE, decision_states, measure, planner_fields
    from lmjx.mapfile.read import load_map
    from lmjx.planner.trial import make_simulator

    m = load_map(plan_map)
    decisions = decision_states(robot, {"case2": m}, (1,), 1, 1, 16, first_seed=5)  # one decision: seconds
    task = resolve_task(1, robot, "hard")
    fields = planner_fields(robot, {"case2": m}, (1,))
    ref = {1: make_simulator(robot, task, "cpu", servo=SERVO)}
    same = measure(robot, decisions, ref, ref, RESCORE, fields)
    assert same["decisions"] == len(decisions) == 1 and same["rescore"] == {"top": 8, "draws": 8}
    assert same["same_choice"] == 1.0 and same["choice_gap_m"]["max"] == 0.0
    rescored = sum(r["rescored_ends"] for r in same["per_decision"])
    assert rescored == 7 * same["candidates"]  # every candidate (fewer than 8 each) from 7 redrawn starts
    assert same["target_end_diff_m"]["n"] == same["candidates"] + rescored and same["target_end_diff_m"]["max"] == 0
    stiff = {1: make_simulator(robot, task, "cpu", servo="playback")}
    other = measure(robot, decisions, stiff, ref, RESCORE, fields)
    assert other["target_end_diff_m"]["max"] > 1e-3 and other["non_finite"] == 0


# ---------------------------------------------------------------- the simulator itself

try:
    import warp  # noqa: F401

    HAVE_WARP = True
except ImportError:
    HAVE_WARP = False
needs_warp = pytest.mark.skipif(
    not HAVE_WARP, reason="warp-lang is not installed (requirements-test.lock, or pip install -e '.[test]')"
)
NO_CUDA = warp_problem()  # why the GPU simulator cannot run on a CUDA GPU here (None: it can)
CUDA = NO_CUDA is None


def _same_results(a: np.ndarray, b: np.ndarray) -> None:
    """Two runs of the same candidates agree: to float32's last bits on Warp's CPU device
    (atol 1e-5: a run there in another batch differed by 1.2e-6 in a quaternion, 2026-11-26);
    on a GPU up to its run-to-run spread (contacts are collected with atomics, so their order, and
    the last bits of a solve, vary between launches): nearly every coordinate the same, and
    a candidate whose outcome turns on a contact chain within 2 cm (measured on an H100,
    2026-11-23: six default runs of the same two candidates ended up to 1.05 cm apart, the
    runs split between two outcomes)."""
    if not CUDA:
        np.testing.assert_allclose(a, b, atol=1e-5)
        return
    d = np.abs(a[..., :3] - b[..., :3])
    assert np.median(d) < 1e-6 and d.max() < 2e-2, (np.median(d), d.max())


def _sim_config(**kw):
    """On a CUDA GPU the defaults; else Warp's CPU device with small batches."""
    return GpuSimConfig(**kw) if CUDA else GpuSimConfig(device="cpu", buckets=(2, 4), segment=4, **kw)


@pytest.fixture(scope="module")
def candidates(robot, small_map):
    """The shared case-2 map's actions over the target for Scenario 3, checked against the
    table and the arm only (these tests compare simulators on the same actions, offered by
    the planner or not: this small map offers none in the hard scenarios); whole actions on a
    GPU, their last 0.2 s on Warp's CPU device, which is far slower."""
    from lmjx.bench.planner import candidate_actions

    n = 64 if CUDA else 4
    _mf, sc, scene, objects, tp, acts = candidate_actions(robot, str(small_map), 3, n, 0, planner_scene=False)
    if not CUDA:
        acts = [replace(a, q=a.q[-(6 + 2 * i) :], qd=a.qd[-(6 + 2 * i) :]) for i, a in enumerate(acts)]
    return sc, scene, objects, tp.park, acts


@needs_warp
@pytest.mark.parametrize("servo", ["playback", "robot"])
def test_gpu_simulator_matches_c_mujoco(robot, candidates, servo):
    """Both servo models (`PlannerConfig.servo`): "robot" limits each joint's torque
    (`jnt_actfrcrange`) and tracks with the robot's softer gains."""
    from lmjx.planner.trial import planner_physics

    sc, scene, objects, q0, acts = candidates
    physics = planner_physics(robot, servo)
    if servo != "playback":
        scene = build_scene(robot, sc, physics)
    ref = CpuSimulator(scene).simulate(q0, objects, acts)
    sim = GpuSimulator(build_scene(robot, sc, physics, fuse_static=True), config=_sim_config())
    out = sim.simulate(q0, objects, acts)
    assert out.shape == ref.shape and np.isfinite(out).all()
    d = np.hypot(*(out[:, :, :2] - ref[:, :, :2]).reshape(-1, 2).T)
    assert np.median(d) < 1e-4, np.median(d)  # float32 on the device, float64 in C MuJoCo
    target = np.hypot(*(out[:, 0, :2] - ref[:, 0, :2]).T)
    assert np.quantile(target, 0.9) < 2e-3, target  # contact chains amplify rounding in a few
    assert sim.capture_seconds > 0 and sim.steps_run > 0 and sim.reruns == 0


@needs_warp
def test_results_do_not_depend_on_the_batch(robot, candidates):
    """A candidate's result is where its own action ends: the same alone, padded into a
    larger batch, or next to other decisions' candidates from other start states."""
    sc, _scene, objects, q0, acts = candidates
    sim = GpuSimulator(build_scene(robot, sc, fuse_static=True), config=_sim_config())
    short = min(acts[:3], key=lambda a: len(a.q))
    alone = sim.simulate(q0, objects, [short])
    moved = objects.copy()
    moved[1:, 0] += 0.01
    both = sim.simulate_many([(q0, moved, acts[:2]), (q0, objects, [short, acts[2]])])
    _same_results(both[1][:1], alone)
    _same_results(both[0], sim.simulate(q0, moved, acts[:2]))


@needs_warp
def test_overflowing_buffers_are_grown_and_the_batch_rolled_out_again(robot, candidates):
    sc, _scene, objects, q0, acts = candidates
    scene_f = build_scene(robot, sc, fuse_static=True)
    small = GpuSimulator(scene_f, config=_sim_config(rows_per_world=32, contacts_per_world=8))
    out = small.simulate(q0, objects, acts[:2])
    assert small.reruns >= 1 and small.config.rows_per_world > 32 and small.config.contacts_per_world > 8
    _same_results(out, GpuSimulator(scene_f, config=_sim_config()).simulate(q0, objects, acts[:2]))


@pytest.mark.skipif(not CUDA, reason=f"the GPU simulator's agreement test needs a CUDA GPU: {NO_CUDA}")
def test_gpu_simulator_agreement_with_c_mujoco_over_200_decisions(robot, tmp_path):
    """Over 200+ Greedy decisions (up to 64 candidates each) across both failures, the three
    scenarios and 12 trials each, from the trials' starts and after one and two random
    pushes, in the configuration the evaluation runs: both simulators with the planner's servo
    model "robot" (`SERVO`), the pick Greedy's rescored choice (its 8 best candidates again from
    7 redrawn starts, `RESCORE`) by the planner's score.  The GPU simulator picks C MuJoCo's
    action, or one within 1 cm of C MuJoCo's best by C MuJoCo's rescored score, in at least
    95 % of them; target ends (every candidate, and the rescored ones both simulated) a median
    at most 0.1 mm from C MuJoCo's; nothing non-finite.

    Out of sample: maps of seed 4049 (`MAP_SEED`), decisions from trial seeds 700-711
    (`FIRST_SEED`; "real" worlds 10,700-10,711), and these thresholds were chosen before the
    test's first run in this configuration and must not be changed after it; no earlier run
    used those seeds.

    Maps: LMJX_TEST_MAPS (a folder with case1.h5 and case2.h5 built with `lmjx build-map
    --failure caseN --edges 100000 --seed 4049`) or built here.  LMJX_TEST_DECISIONS: the
    decisions built before from those maps (`benchmarks/agreement_run.py MAPS
    --save-decisions FILE`, which takes the host's cores: the longest part) instead of building
    them here.  LMJX_TEST_REPORT: write the figures there (JSON)."""
    from lmjx.evaluation.agreement import load_decisions, out_of_sample
    from lmjx.evaluation.evaluate import load_maps
    from lmjx.planner.trial import make_simulator

    folder = Path(os.environ.get("LMJX_TEST_MAPS", tmp_path))
    if "LMJX_TEST_MAPS" not in os.environ:
        from lmjx.edges.chunk import build_bundle
        from lmjx.mapfile.bundle import BundleConfig
        from lmjx.mapfile.write import write_map
        from lmjx.reach.reachability import ReachConfig, reach_map

        for f in ("case1", "case2"):
            reach = reach_map(f, ReachConfig(seed=MAP_SEED), robot=robot)
            bundle = build_bundle(reach, BundleConfig(edges=100_000, seed=MAP_SEED), robot=robot)
            write_map(folder / f"{f}.h5", reach, bundle, robot)
    maps = load_maps(robot, ("case1", "case2"), folder)
    for f, m in maps.items():
        assert m.edges.config.seed == MAP_SEED and m.reach.config.seed == MAP_SEED, f"{f}: not the out-of-sample map"
    built = None
    if "LMJX_TEST_DECISIONS" in os.environ:
        blob = load_decisions(os.environ["LMJX_TEST_DECISIONS"])  # refuses other seeds' decisions
        assert blob["maps"] == {f: {"seed": MAP_SEED, "edges": int(m.edges.n_edges)} for f, m in maps.items()}
        assert blob["first_seed"] == FIRST_SEED
        built = (blob["decisions"], blob["seconds"], blob["workers"])
    tasks = {s: resolve_task(s, robot, "hard") for s in (1, 2, 3)}
    report = out_of_sample(
        robot,
        maps,
        {s: make_simulator(robot, tasks[s], "gpu", servo=SERVO) for s in tasks},
        {s: make_simulator(robot, tasks[s], "cpu", servo=SERVO) for s in tasks},
        built=built,
    )
    if "LMJX_TEST_REPORT" in os.environ:
        Path(os.environ["LMJX_TEST_REPORT"]).write_text(json.dumps(report, indent=1))
    assert (report["servo"], report["rescore"]) == ("robot", {"top": 8, "draws": 8})
    assert report["decisions"] >= 200
    assert report["non_finite"] == 0
    assert report["target_end_diff_m"]["median"] <= 1e-4, report["target_end_diff_m"]
    assert report["same_or_within_1cm"] >= 0.95, report["same_or_within_1cm"]
