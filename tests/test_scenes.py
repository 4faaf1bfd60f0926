"""Scene files (docs/SCENES.md): the shipped ones are the paper's scenarios to the last bit,
planned and evaluated alike through --scenario and --scene; a user's scene plans with every
ASM; every mistake is refused in one line before anything is simulated.  Cheap: no map but
the planner tests' `plan_map`, trials of one or two actions."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import TINY_ARM, cli

import lmjx
from lmjx.errors import ConfigError, SceneError
from lmjx.model.robot import load_robot
from lmjx.sim.scenarios import resolve_task, sample_layout, scenario
from lmjx.sim.scenefile import load_scene, read_scene, record_task, scene_record, scene_text, shipped_scene

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "examples" / "my_bench.toml"
SEEDS = (0, 1, 7, 123, 5000)  # layouts compared (none of the evaluation's trial seeds)


@pytest.mark.parametrize("tasks", ["paper", "hard"])
@pytest.mark.parametrize("n", [1, 2, 3])
def test_shipped_files_are_the_scenarios_to_the_bit(n, tasks):
    """Each file reads as the scenario's definition (dataclass equality: every float exact),
    placed for the Panda, the UR5e and an arm of another size (the test arm, scale 0.815) as
    `resolve_task` places it, with the same layouts; and it is the text `scene_text` writes."""
    path = shipped_scene(n, tasks)
    f = read_scene(path)
    sc = scenario(n, 1.0, tasks)
    assert f.scenario == sc and f.scale_with_robot and f.name == f"scenario {n}"
    header = "\n".join(line[2:] for line in path.read_text().splitlines() if line.startswith("# "))
    assert path.read_text() == scene_text(sc, f.name, True, header)
    for robot in (load_robot("panda"), load_robot("ur5e"), load_robot(str(TINY_ARM))):
        want = resolve_task(n, robot, tasks)
        # (the test arm's scaled clutter overlaps: its geometry is not checked, only placed)
        got = lmjx.load_scene(path, robot) if robot.profile.task_scale == 1.0 else f.task(robot)
        assert got == want, robot.key
        for seed in SEEDS:
            assert np.array_equal(sample_layout(got.scenario, seed).poses, want.layout(seed).poses)
    assert load_robot(str(TINY_ARM)).profile.task_scale != 1.0  # (the scaling is exercised)


def _layout_with_one_jitter(sc, seed: int) -> np.ndarray:
    """The layouts as drawn with one scalar jitter for every object (`sample_layout` before
    objects had jitters of their own): the frozen evaluation's layouts."""
    from lmjx.sim.scenarios import _separated

    rng = np.random.default_rng(seed)
    for _ in range(200):
        d = rng.uniform(-sc.jitter, sc.jitter, (len(sc.movable), 2))
        yaw = rng.uniform(-sc.yaw_jitter, sc.yaw_jitter, len(sc.movable))
        poses = np.array([[b.x + dx, b.y + dy, b.yaw + w] for b, (dx, dy), w in zip(sc.movable, d, yaw, strict=True)])
        if _separated(sc.movable, poses, sc.fixed):
            return poses
    raise AssertionError("no layout")


@pytest.mark.parametrize("n", [1, 2, 3])
def test_layouts_draw_as_with_one_jitter(n):
    for tasks in ("paper", "hard"):
        sc = scenario(n, 1.0, tasks)
        for seed in (*SEEDS, 1000 * n + 3):
            assert np.array_equal(sample_layout(sc, seed).poses, _layout_with_one_jitter(sc, seed))


def test_per_object_jitter_and_a_goal_by_distance_and_angle(tmp_path):
    """A box's own jitter bounds its draws; a goal given by distance and angle from the target
    is placed as the paper set places its goals; the docs' example block is a valid scene."""
    task = lmjx.load_scene(BENCH)
    sc = task.scenario
    book = next(b for b in sc.movable if b.name == "book")
    assert book.jitter == 0.005 and sc.jitter == 0.01 and sc.table_friction == 0.45 and sc.target.friction == 0.4
    poses = np.array([task.layout(s).poses for s in range(20)])
    i = [b.name for b in sc.movable].index("book")
    assert np.abs(poses[:, i, :2] - [book.x, book.y]).max() <= 0.005
    assert np.abs(poses[:, 0, :2] - [sc.target.x, sc.target.y]).max() > 0.005
    a = np.radians(80.0)
    assert sc.goal_center == (0.42 + 0.15 * np.cos(a), 0.36 + 0.15 * np.sin(a))
    block = re.search(r"```toml\n(.*?)```", (ROOT / "docs" / "SCENES.md").read_text(), re.S).group(1)
    (tmp_path / "doc.toml").write_text(block)
    assert lmjx.load_scene(tmp_path / "doc.toml").scenario.obstacles[0].name == "mug"


def _no_wall_time(record: dict) -> dict:
    """A record without what differs between two runs of the same trial: wall-clock times and
    the id of the run that wrote it (provenance)."""
    wall = {"planning_s": 0, "compile_s": 0}
    each = wall | {"latency_s": 0, "phase_s": 0, "shared_s": 0}  # (and each decision's times)
    return {k: v for k, v in record.items() if k != "run"} | wall | {"steps": [s | each for s in record["steps"]]}


def test_a_trial_through_scene_file_equals_the_scenarios(plan_map, tmp_path):
    """lmjx plan and lmjx evaluate give the same records through --scenario N and --scene(s)
    of the shipped file (a trial that acts: seed 0 of scenario 1 on this map)."""
    args = ("--map", plan_map, "--asm", "random", "--max-actions", "2", "--seed", "0", "--json")
    by_number = json.loads(cli("plan", "--scenario", "1", *args).ok().stdout)
    by_file = json.loads(cli("plan", "--scene", shipped_scene(1, "paper"), *args).ok().stdout)
    assert by_number["actions"] > 0 and by_number["task"] == "scenario 1"
    assert _no_wall_time(by_file) == _no_wall_time(by_number)
    ev = ("evaluate", "--failures", "case2", "--asms", "random", "--trials", "1", "--max-actions", "1",
          "--maps", plan_map.parent, "--out")  # fmt: skip
    cli(*ev, tmp_path / "n", "--scenarios", "2").ok()
    cli(*ev, tmp_path / "f", "--scenes", shipped_scene(2, "paper")).ok()
    n, f = (json.loads((tmp_path / d / "results.json").read_text())["trials"] for d in ("n", "f"))
    assert [_no_wall_time(r) for r in n] == [_no_wall_time(r) for r in f] and n[0]["seed"] == 2000


def test_a_users_scene_plans_with_every_asm(plan_map):
    """examples/my_bench.toml (written by hand: its own sizes, masses, frictions, a fixed post,
    a goal by distance and angle) planned with each ASM on the CPU, the planner's defaults."""
    for asm in ("random", "lazy", "greedy"):
        r = json.loads(cli("plan", "--map", plan_map, "--scene", BENCH, "--asm", asm, "--max-actions", "1",
                           "--candidates", "4", "--sim", "cpu", "--json").ok().stdout)  # fmt: skip
        assert r["task"] == "my bench" and r["tasks"] == "custom" and r["scenario"] == 0, r
        assert r["actions"] == 1 and r["steps"][0]["edge"] >= 0, (asm, r["end"], r["steps"])


def test_scenes_are_numbered_by_file_else_by_place(robot, tmp_path):
    from lmjx.cli.evaluate import scene_tasks

    first = shipped_scene(1, "hard")
    tasks = scene_tasks([str(BENCH), str(first), str(BENCH)], robot)
    assert [t.number for t in tasks] == [2, 1, 3] and tasks[1] == resolve_task(1, robot, "hard")
    with pytest.raises(SceneError, match="both have number = 1"):
        scene_tasks([str(first), str(shipped_scene(1, "paper"))], robot)


BASE = BENCH.read_text()


def _edit(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


# six boxes in a row, each 0.5 mm further apart than the layouts' gap: the jitter (1 cm) makes them overlap
ROW = "".join(
    f'[[obstacles]]\nname = "row{i}"\nsize = [0.05, 0.05, 0.05]\nposition = [{0.42 + 0.0545 * i:.4f}, 0.25]\n\n'
    for i in range(6)
)
# (a change to examples/my_bench.toml, what the one-line error says)
BAD = [
    ((BASE.replace('format = "lmjx-scene/1"', 'format = "lmjx-scene/2"')), 'this lmjx reads "lmjx-scene/1"'),
    (_edit(BASE, "budget = 12", "budget = 12\ncolour = 3"), "unknown key 'colour'; the keys are: format, name"),
    (_edit(BASE, "mass = 0.2 ", "masses = 0.2 "), "target: unknown key 'masses'; the keys there are: size"),
    (_edit(BASE, "mass = 0.2 ", "mass = -1 "), "target.mass: give a number above 0 and at most 100, got -1"),
    (_edit(BASE, "size = [0.05, 0.05, 0.05]", 'size = "5 cm"'), "target.size: give [..., ..., ...], 3 numbers"),
    (_edit(BASE, "budget = 12", "budget = 0"), "budget: give a whole number 1 to 10000, got 0"),
    (_edit(BASE, '[[obstacles]]\nname = "mug"', '[[obstacles]]\nname = "book"'), "the name 'book' is given twice"),
    (_edit(BASE, 'name = "mug"', 'name = "link3"'), "the robot's model has a body 'link3'"),
    (_edit(BASE, "distance = 0.15 ", "center = [0.4, 0.5]\ndistance = 0.15 "), "give either center"),
    ("format = [", "not TOML"),
    # geometry
    (_edit(BASE, "position = [0.53, 0.35]", "position = [0.45, 0.36]"), "'target' and 'mug' overlap at their nominal"),
    (_edit(BASE, "[[fixed]]", ROW + "[[fixed]]"), "jitter leaves them apart in only 0 of 200 draws"),
    (_edit(BASE, "position = [0.42, 0.36]", "position = [0.42, 1.2]"), "'target' at (0.42, 1.2) is off the table"),
    (_edit(BASE, "position = [0.62, 0.56]", "position = [0.02, 0.0]"), "'shelf_post' at (0.02, 0) passes through"),
    (_edit(BASE, "distance = 0.15 ", "distance = 2.0 "), "the goal region reaches off the table"),
    (_edit(BASE, "position = [0.62, 0.56]", "position = [0.62, 1.5]"),
     "the fixed obstacle 'shelf_post' at (0.62, 1.5) reaches off the table"),
    # a slab under the whole goal region (centred at the target + 15 cm at 80 degrees)
    (_edit(BASE, "size = [0.04, 0.04, 0.3]\nposition = [0.62, 0.56]",
           "size = [0.16, 0.16, 0.02]\nposition = [0.446, 0.508]"),
     "is covered by the fixed obstacle 'shelf_post': the target cannot rest anywhere in it"),
]  # fmt: skip


@pytest.mark.parametrize("text,message", BAD, ids=[f"bad{i}" for i in range(len(BAD))])
def test_a_bad_scene_is_one_line_and_exit_2(text, message, tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    cli("scenarios", "--check", path).one_line_error(message)
    with pytest.raises(SceneError, match=re.escape(message)):
        lmjx.load_scene(path)


def test_a_goal_out_of_the_maps_reach_is_refused_with_the_map(plan_map, tmp_path):
    """A goal behind the robot's base, off the map's task plane, has no reachable cell under
    it: refused by scenarios --check --map, plan --scene and evaluate --scenes, before any
    simulation; without a map the same file passes."""
    path = tmp_path / "far.toml"
    path.write_text(_edit(BASE, "distance = 0.15 ", "center = [-0.35, -0.9]\n#").replace("angle = 80.0", ""))
    ok = cli("scenarios", "--check", path, "--json").ok()
    assert json.loads(ok.stdout)["map"] is None
    message = "no reachable cell of the map (NPM or PM) lies under the goal region centred at (-0.35, -0.9)"
    cli("scenarios", "--check", path, "--map", plan_map).one_line_error(message)
    cli("plan", "--map", plan_map, "--scene", path, "--asm", "greedy").one_line_error(message)
    cli("evaluate", "--failures", "case2", "--scenes", path, "--maps", plan_map.parent,
        "--out", tmp_path / "e").one_line_error(message)  # fmt: skip
    assert not (tmp_path / "e").exists()
    cli("plan", "--map", plan_map, "--scene", tmp_path / "none.toml", "--asm", "lazy").one_line_error("no such file")
    cli("plan", "--map", plan_map, "--scene", path, "--tasks", "hard", "--asm", "lazy").one_line_error(
        "leave out --tasks"
    )
    cli("plan", "--map", plan_map, "--scene", path, "--scenario", "1", "--asm", "lazy").one_line_error(
        "not allowed with argument"
    )
    check = cli("scenarios", "--check", BENCH, "--map", plan_map).ok().stdout
    assert "ok (my bench: the target, 2 movable boxes, 1 fixed obstacle," in check and "goal reached on" in check


def test_a_record_of_its_scene_rebuilds_the_task(robot):
    """A trial's record of its scene (`scene_record`) rebuilds the task it ran (`record_task`)
    with a matching digest: a shipped scenario by its number and task set (through its file
    too), a user's scene by its file's text as read; an edited definition tells, a record
    lmjx does not write is one line."""
    shipped = resolve_task(2, robot, "hard")
    for task in (shipped, load_scene(shipped_scene(2, "hard"), robot)):
        rec = scene_record(task, robot)
        assert rec["kind"] == "shipped" and (rec["scenario"], rec["tasks"]) == (2, "hard")
        assert record_task(json.loads(json.dumps(rec)), robot, "trial") == (shipped, True)
    mine = load_scene(BENCH, robot)
    rec = scene_record(mine, robot)
    assert rec["kind"] == "scene" and rec["text"] == BENCH.read_text() and rec["name"] == "my bench"
    back, same = record_task(json.loads(json.dumps(rec)), robot, "trial")
    assert same and back == mine and back.scenario == mine.scenario
    edited = rec | {"text": rec["text"].replace("budget = 12", "budget = 13")}
    assert record_task(edited, robot, "trial")[1] is False
    with pytest.raises(ConfigError, match=r"^trial: its record of the scene is not one lmjx writes"):
        record_task({"kind": "movie"}, robot, "trial")


def test_evaluate_runs_a_users_scene_beside_a_shipped_one(plan_map, tmp_path, robot):
    """`lmjx evaluate --scenes` with a hand-written scene and a shipped one (the task sets
    'custom+paper'): its task digest is that of the scenes' definitions, the report names
    the user's scene, each record keeps its scene."""
    from lmjx.evaluation.provenance import task_digest

    out = tmp_path / "ev"
    cli("evaluate", "--failures", "case2", "--asms", "random", "--trials", "1", "--max-actions", "1",
        "--maps", plan_map.parent, "--out", out, "--scenes", BENCH, shipped_scene(1, "paper")).ok()  # fmt: skip
    data = json.loads((out / "results.json").read_text())
    run, trials = data["runs"][0], data["trials"]
    assert run["tasks"]["set"] == "custom+paper" and len(trials) == 2
    from lmjx.cli.evaluate import scene_tasks

    scenes = scene_tasks([str(BENCH), str(shipped_scene(1, "paper"))], robot)
    assert run["tasks"]["digest"] == task_digest(robot, "custom+paper", (2, 1), tuple(scenes))
    kinds = {t["scenario"]: t["scene"]["kind"] for t in trials}
    assert kinds == {1: "shipped", 2: "scene"}
    report = (out / "report.md").read_text()
    assert "| case2 | 2 (my bench) | random |" in report and "scenario 2 is my bench (" in report
