"""The Python API matches the command line: names where the CLI takes names (a robot's name
or path, a failure spec) as well as objects, one-line reprs, and `build_map` / `plan_task`
giving what `lmjx build-map` / `lmjx plan` give.  Cheap: a 16-cell map on the shared case-2
program, the four-joint test arm's build against its fixture map, Random trials on the
shared small map."""

from __future__ import annotations

import json
import time

import pytest
from conftest import TINY_ARM, TINY_MAP, cli
from test_edgestream import attributes, same_datasets

import lmjx
from lmjx.errors import ConfigError, FailureSpecError, MapFileError
from lmjx.model.robot import MODEL_PATH

TINY = lmjx.ReachConfig(cell=0.25, attempts=2)  # 4 x 4 cells, one PM and one NPM attempt: two launches


@pytest.fixture(scope="module")
def tiny_case2(robot):
    return lmjx.reach_map("case2", TINY, robot=robot)


def test_exports_are_listed_and_documented():
    for name in lmjx.__all__:
        if name == "__version__":
            continue
        assert name in dir(lmjx) and name in lmjx.__doc__, name
        assert getattr(lmjx, name).__doc__, name
    for fn in (lmjx.build_map, lmjx.plan_task, lmjx.reach_map, lmjx.load_map, lmjx.write_reach_map):
        assert ">>> " in fn.__doc__, fn.__name__  # a runnable example each


def test_a_robot_by_name_path_or_object_gives_the_same_map(robot, tiny_case2):
    failure = lmjx.parse_failure("case2", "panda")
    res = lmjx.reach_map(failure, TINY, robot="panda")
    assert (res.labels == tiny_case2.labels).all() and res.failure.locked == failure.locked
    # every way of naming the Panda is the one robot (its compiled kernels shared)
    assert lmjx.load_robot("panda") is lmjx.load_robot(MODEL_PATH) is lmjx.load_robot() is robot
    assert lmjx.parse_failure("J6=0.935,J7=-0.7193", MODEL_PATH).locked == failure.locked
    assert lmjx.parse_failure("case1", "ur5e").locked == ((4, 4.6974), (5, 1.5658))
    assert lmjx.reach_config("ur5e").interaction_points == lmjx.load_robot("ur5e").default_ips


def test_names_and_objects_that_do_not_fit_are_refused(robot):
    with pytest.raises(ConfigError, match="unknown robot 'ur6'"):
        lmjx.reach_map("case2", TINY, robot="ur6")
    with pytest.raises(FailureSpecError, match="7 joints, ur5e has 6"):
        lmjx.reach_map(lmjx.parse_failure("case2"), TINY, robot="ur5e")
    with pytest.raises(FailureSpecError, match="J8 does not exist"):
        lmjx.parse_failure("J8=0", robot)
    with pytest.raises(lmjx.LmjxError, match="not 42"):
        lmjx.reach_map(42, TINY)  # type: ignore[arg-type]


def test_reprs_are_one_short_line(robot, tiny_case2, small_map):
    from lmjx.mapfile.bundle import BundleConfig
    from lmjx.types import PlannerConfig

    with lmjx.load_map(small_map) as m:
        objects = [robot, m, m.robot, m.reach, m.edges, m.failure, tiny_case2, TINY, BundleConfig(edges=200),
                   PlannerConfig().paper()]  # fmt: skip
        texts = [repr(o) for o in objects]
    for text in texts:
        assert "\n" not in text and len(text) < 250 and "array(" not in text, text
    assert texts[7] == "ReachConfig(cell=0.25, attempts=2)" and texts[8] == "BundleConfig(edges=200)"
    assert "panda" in texts[0] and "7 joints" in texts[0] and "case2" in texts[5]


def test_write_reach_map_names_the_robot_of_the_result(tiny_case2, tmp_path):
    path = tmp_path / "reach.h5"
    lmjx.write_reach_map(path, tiny_case2)
    with lmjx.load_map(path, robot="panda") as m:
        assert m.robot.key == "panda" and (m.reach.labels == tiny_case2.labels).all() and m.edges is None
    with pytest.raises(MapFileError, match="not 'ur5e'"):
        lmjx.load_map(path, robot="ur5e")


def test_build_map_writes_what_build_map_writes(tiny_map, tmp_path):
    """The test arm's build (TINY_MAP) by the function: the datasets and attributes of the
    command's file."""
    args = dict(zip(TINY_MAP[::2], TINY_MAP[1::2], strict=True))
    out = tmp_path / "api.h5"
    t0 = time.perf_counter()
    b = lmjx.build_map(args["--failure"], robot=TINY_ARM, out=out, edges=int(args["--edges"]),
                       cell=float(args["--cell"]), seed=int(args["--seed"]), chunk=int(args["--chunk"]))  # fmt: skip
    wall = time.perf_counter() - t0
    assert same_datasets(tiny_map, out) == [] and attributes(tiny_map) == attributes(out)
    s = b.summary()
    assert s["failure"] == "J4=0.5" and s["edges"]["edges_valid"] > 0 and s["reach"]["cell_m"] == 0.05
    # compiling by stage, each program once (the edges' starts share the reach map's IK
    # program); the run built the fixture's map already (maybe in another worker), so each
    # program is in this process or loaded from the run's compile cache: seconds at most.
    # The whole is the wall time during which something compiled or waited for another
    # process compiling the same program: never above the build's own wall time
    stages = s["compile_seconds_by_stage"]
    assert set(stages) == {"reach", "edges", "index"}
    assert 0.0 <= s["compile_seconds"] <= wall
    assert s["edges"]["compile_seconds"] == stages["edges"] and s["compile_seconds"] < 5.0
    assert s["compiled_for_later"] is None  # not on a CPU unless asked for
    assert "edges kept of 1,200 sampled" in repr(b)
    with b.load() as m:
        assert m.edges.n_edges == s["edges"]["edges_valid"]


def test_plan_task_gives_what_plan_prints(small_map):
    args = ("--scenario", "1", "--asm", "random", "--seed", "0", "--max-actions", "2")
    want = json.loads(cli("plan", "--map", small_map, *args, "--json").ok().stdout)
    r = lmjx.plan_task(small_map, scenario=1, asm="random", seed=0, max_actions=2)
    assert _no_wall_time(r.summary()) == _no_wall_time(want)
    assert r.actions <= 2 and len(r.steps) >= 1 and "random, seed 0" in repr(r)
    with lmjx.load_map(small_map) as m:  # an open map does too
        again = lmjx.plan_task(m, 1, "random", seed=0, max_actions=2).summary()
        assert _no_wall_time(again) == _no_wall_time(want)


def _no_wall_time(summary: dict) -> dict:
    """A trial's summary without its wall times (planning_s and compile_s, its own and every
    step's: only the run that compiled a kernel first has compile_s)."""
    wall = {"planning_s": 0, "compile_s": 0}
    each = wall | {"latency_s": 0, "phase_s": 0, "shared_s": 0}  # (and each decision's times)
    return summary | wall | {"steps": [s | each for s in summary["steps"]]}


def test_plan_task_refuses_in_one_line(small_map, tiny_case2, tmp_path):
    reach_only = tmp_path / "reach.h5"
    lmjx.write_reach_map(reach_only, tiny_case2)
    for kwargs, message in (
        ({"scenario": 4}, "scenario 4 does not exist"),
        ({"scenario": 1, "asm": "clever"}, "unknown action selection mechanism"),
        ({"scenario": 1, "tasks": "easy"}, "unknown task set"),
        ({"scenario": 1, "failure": "case1"}, "not case1"),
        ({"scenario": 1, "max_actions": 0}, "max_actions must be at least 1"),
    ):
        with pytest.raises(lmjx.LmjxError, match=message):
            lmjx.plan_task(small_map, **kwargs)
    with pytest.raises(ConfigError, match="has no edges; build it with: lmjx build-map --failure case2"):
        lmjx.plan_task(reach_only, 1)
    with pytest.raises(ConfigError, match="unknown device"):
        lmjx.use_device("tpu")
    assert lmjx.use_device("cpu") == "cpu"


def test_plan_task_takes_a_resolved_task_and_the_planners_keys(robot, small_map, tmp_path):
    """A Task resolved for the map's robot plans as its number does; one placed for another
    robot is refused; the levers as keys (a mapping or a TOML file) plan as the keywords."""
    from lmjx.sim.scenarios import resolve_task

    want = lmjx.plan_task(small_map, 1, "random", seed=0, max_actions=2, late_start=True).summary()
    assert want["asm_settings"]["late_start"] is True
    task = resolve_task(1, robot, "paper")
    assert (task.number, task.tasks, task.budget, task.robot) == (1, "paper", 30, "panda")
    levers = tmp_path / "levers.toml"
    levers.write_text("late_start = true\n")
    for got in (
        lmjx.plan_task(small_map, task, "random", seed=0, max_actions=2, planner={"late_start": True}),
        lmjx.plan_task(small_map, 1, "random", seed=0, planner={"late_start": True, "max_actions": 2}),
        lmjx.plan_task(small_map, 1, "random", seed=0, max_actions=2, planner=levers),
    ):
        assert _no_wall_time(got.summary()) == _no_wall_time(want)
    with pytest.raises(ConfigError, match="scenario 1 is placed for the robot ur5e, not panda"):
        lmjx.plan_task(small_map, resolve_task(1, lmjx.load_robot("ur5e")), "random")
    with pytest.raises(ConfigError, match="planner: rescore_top takes a whole number at least 0, got -1"):
        lmjx.plan_task(small_map, 1, "random", planner={"rescore_top": -1})
