"""Scene files: a user's table as data (TOML, format "lmjx-scene/1"; docs/SCENES.md).

A scene file describes what a scenario holds (`lmjx.sim.scenarios.Scenario`): the table's
friction; the target and the movable objects (boxes, or upright cylinders with `shape =
"cylinder"`, a radius and a height: `Cylinder`; size, mass, friction, nominal pose,
jitter); the fixed obstacles (boxes or cylinders); the goal region; the action budget.  `read_scene` checks every key
(an unknown key, a wrong type or a value out of range is a one-line `SceneError` naming the
key and the fix) and gives the scenario as written; `load_scene` places it for a robot and
checks its geometry before anything is simulated (`lmjx.sim.scenecheck`); `scene_text`
writes a scenario back in the same format, floats exactly (the shipped scenarios'
files, lmjx/sim/scenes/, are its output: `shipped_scene`).  A task read from a file is a
`SceneTask`: the Task with the file's text, so that every record of a trial can carry its
scene (`scene_record`: a shipped scenario's number and task set, else the file's text, each
with `scene_digest`, the digest of the task's definition) and a trial can be rebuilt from its
record alone (`record_task`).  Positions are metres in the
robot's base frame on the table top (x forward, y to the robot's left), yaws radians about
z.  Nothing here simulates.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import tomllib
from collections.abc import Iterable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lmjx.errors import ConfigError, SceneError
from lmjx.sim.scenarios import (
    FIXED_RGBA,
    OBSTACLE_RGBA,
    SCENARIOS,
    TARGET_RGBA,
    TASK_SETS,
    Box,
    Cylinder,
    Scenario,
    Task,
    placed,
    resolve_task,
)

if TYPE_CHECKING:
    from lmjx.mapfile.read import MapFile
    from lmjx.model.robot import Robot

FORMAT = "lmjx-scene/1"
SCENES_DIR = Path(__file__).parent / "scenes"
CUSTOM = "custom"  # the task set of a scene file that names none
RESERVED = ("target", "table", "goal")  # names the scene's MuJoCo model uses for other things
NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_-]{0,47}$")

# The keys of each table of a scene file, with what each takes (the message of a mistake).
TOP = {
    "format": f'the format, "{FORMAT}"',
    "name": "how messages and results call the scene (default: the file's name)",
    "title": "a short title (default: the name)",
    "description": "what the task is, in words",
    "number": "a whole number 1 to 99: results record it as the scenario, and trial seeds derive from it",
    "task_set": f'the task set it belongs to, a word (default "{CUSTOM}")',
    "budget": "the action budget, a whole number at least 1 (default 30)",
    "scale_with_robot": "true: positions scale with the robot's size (as the shipped scenarios'); default false",
    "table": "a table: friction",
    "jitter": "a table: position, yaw",
    "target": "a table: the target (a box or a cylinder)",
    "obstacles": "an array of tables ([[obstacles]]): the movable objects (boxes or cylinders)",
    "fixed": "an array of tables ([[fixed]]): the fixed obstacles",
    "goal": "a table: the goal region",
}
TABLE = {"friction": "the table top's sliding friction, a number above 0 (default 0.5)"}
JITTER = {
    "position": "[m] how far each trial moves the movable boxes in x and y, a number at least 0 (default 0.02)",
    "yaw": "[rad] how far each trial turns them, a number at least 0 (default 0.26)",
}
SHAPES = ("box", "cylinder")
BOX = {
    "size": "[m] the box's full size [x, y, z], three numbers above 0",
    "shape": 'its shape, "box" (default: with size) or "cylinder" (an upright one: with radius and height)',
    "radius": "[m] the cylinder's radius, a number above 0 and at most 1",
    "height": "[m] the cylinder's height, a number above 0 and at most 2",
    "position": "[m] its centre's nominal [x, y] on the table",
    "yaw": "[rad] its nominal turn about z (default 0)",
    "friction": "its sliding friction, a number above 0 (default 0.5)",
    "color": "[r, g, b, a], four numbers 0 to 1",
}
MOVABLE = {
    **BOX,
    "mass": "[kg] a number above 0 (default 0.1)",
    "jitter": "[m] its own position jitter (default: the scene's)",
    "yaw_jitter": "[rad] its own yaw jitter (default: the scene's)",
}
OBSTACLE = {"name": "a word unique in the scene (default obstacle1, obstacle2, ...)", **MOVABLE}
FIXED = {
    "name": "a word unique in the scene (default fixed1, fixed2, ...)",
    **BOX,
    "z": "[m] its centre's height above the table top (default: resting on it)",
}
GOAL = {
    "size": "[m] the goal region's full size [x, y], two numbers above 0",
    "center": "[m] its centre [x, y] (or distance and angle)",
    "distance": "[m] its centre's distance from the target's nominal position (with angle)",
    "angle": "[deg] the direction of that distance, counter-clockwise from x (with distance)",
}


@dataclass(frozen=True, eq=False)
class SceneTask(Task):
    """A Task read from a scene file, with the file's text as read (`text`) and its path
    (`file`): what a trial's record keeps of its scene (`scene_record`).  It equals the Task
    of the same definition, robot and name, whatever file it came from (the text is where it
    came from, not what the task is)."""

    text: str = ""
    file: str = ""

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Task):
            return NotImplemented
        return (self.scenario, self.robot, self.name) == (other.scenario, other.robot, other.name)

    __hash__ = Task.__hash__


@dataclass(frozen=True)
class SceneFile:
    """A scene file as written: its scenario (positions as the file gives them), what it is
    called, whether its positions scale with the robot's size, and its text as read."""

    path: Path
    scenario: Scenario
    name: str
    scale_with_robot: bool
    text: str = ""

    def task(self, robot: Robot) -> SceneTask:
        """The scene placed for `robot` (its positions scaled by the robot's `task_scale`
        where `scale_with_robot`), as the Task the planner and the evaluation take (with the
        file's text: `SceneTask`)."""
        sc = placed(self.scenario, robot.profile.task_scale) if self.scale_with_robot else self.scenario
        return SceneTask(sc, robot.key, self.name, text=self.text, file=str(self.path))


class _Reader:
    """Checks the values of one scene file; every mistake is one SceneError line."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, where: str, message: str) -> SceneError:
        return SceneError(f"scene {self.path}: {where}{': ' if where else ''}{message}")

    def table(self, data: Any, where: str, keys: dict[str, str], required: tuple[str, ...] = ()) -> dict:
        if not isinstance(data, dict):
            raise self.fail(where, f"must be a table ({'[' + where + ']' if where else 'key = value lines'})")
        for k in data:
            if k not in keys:
                known = ", ".join(keys)
                raise self.fail(where, f"unknown key '{k}'; the keys {'there ' if where else ''}are: {known}")
        for k in required:
            if k not in data:
                raise self.fail(where, f"'{k}' is missing: give {keys[k]}")
        return data

    def number(self, data: dict, key: str, where: str, default: float | None, low: float, high: float,
               above: bool = False) -> float:  # fmt: skip
        if key not in data:
            assert default is not None
            return default
        v = data[key]
        ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
        if ok and (v > low if above else v >= low) and v <= high:
            return float(v)
        bound = f"above {low:g}" if above else f"at least {low:g}"
        raise self.fail(f"{where}{'.' if where else ''}{key}", f"give a number {bound} and at most {high:g}, got {v!r}")

    def vector(self, data: dict, key: str, where: str, n: int, low: float, high: float, above: bool = False) -> tuple:
        v = data[key]
        good = (
            isinstance(v, list)
            and len(v) == n
            and all(isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) for x in v)
        )
        if good and all((x > low if above else x >= low) and x <= high for x in v):
            return tuple(float(x) for x in v)
        bound = f"above {low:g}" if above else f"{low:g}"
        raise self.fail(f"{where}.{key}", f"give [{', '.join('...' for _ in range(n))}], {n} numbers {bound} to "
                                          f"{high:g}, got {v!r}")  # fmt: skip

    def word(self, data: dict, key: str, where: str, default: str) -> str:
        v = data.get(key, default)
        if isinstance(v, str) and NAME.match(v):
            return v
        raise self.fail(f"{where}{'.' if where else ''}{key}", f"give a word of letters, digits, '_' or '-' starting "
                                                               f"with a letter, got {v!r}")  # fmt: skip

    def text(self, data: dict, key: str, default: str) -> str:
        v = data.get(key, default)
        if isinstance(v, str) and "\n" not in v.strip() and len(v) <= 2000:
            return v
        raise self.fail(key, f"give one line of text, got {v!r}")

    def box(self, data: Any, where: str, keys: dict, name: str, movable: bool, rgba: tuple) -> Box:
        d = self.table(data, where, keys)
        shape = d.get("shape", "box")
        if shape not in SHAPES:
            raise self.fail(f"{where}.shape", f'give "box" or "cylinder", got {shape!r}')
        if shape == "box" and ("radius" in d or "height" in d):
            k = "radius" if "radius" in d else "height"
            raise self.fail(where, f"'{k}' is a cylinder's: give a box size = [x, y, z], or shape = \"cylinder\" "
                                   "with radius and height")  # fmt: skip
        if shape == "cylinder" and "size" in d:
            raise self.fail(where, "a cylinder takes radius and height, not size; give radius = ... and height = ...")
        for k in (("size",) if shape == "box" else ("radius", "height")) + ("position",):
            if k not in d:
                raise self.fail(where, f"'{k}' is missing: give {keys[k]}")
        half: tuple[float, ...]
        if shape == "box":
            half = tuple(s / 2 for s in self.vector(d, "size", where, 3, 0.0, 2.0, above=True))
        else:
            r = self.number(d, "radius", where, None, 0.0, 1.0, above=True)
            half = (r, r, self.number(d, "height", where, None, 0.0, 2.0, above=True) / 2)
        x, y = self.vector(d, "position", where, 2, -10.0, 10.0)
        extra: dict[str, Any] = {}
        if movable:
            extra["mass"] = self.number(d, "mass", where, 0.1, 0.0, 100.0, above=True)
            for key, high in (("jitter", 0.5), ("yaw_jitter", math.pi)):
                if key in d:
                    extra[key] = self.number(d, key, where, None, 0.0, high)
        elif "z" in d:
            extra["z"] = self.number(d, "z", where, None, -2.0, 5.0)
        color = self.vector(d, "color", where, 4, 0.0, 1.0) if "color" in d else rgba
        kind = Box if shape == "box" else Cylinder
        return kind(name, half, x, y, yaw=self.number(d, "yaw", where, 0.0, -100.0, 100.0), movable=movable,
                   rgba=color, friction=self.number(d, "friction", where, 0.5, 0.0, 10.0, above=True),
                   **extra)  # fmt: skip


def read_scene(path: str | Path) -> SceneFile:
    """A scene file, every key checked; its scenario as written (not yet placed for a robot,
    its geometry not yet checked: `load_scene`)."""
    p = Path(path)
    try:
        text = p.read_text()
    except FileNotFoundError:
        raise SceneError(f"scene {p}: no such file; give a scene file (docs/SCENES.md)") from None
    except IsADirectoryError:
        raise SceneError(f"scene {p}: is a folder; give a scene file (docs/SCENES.md)") from None
    except (OSError, UnicodeDecodeError) as e:
        raise SceneError(f"scene {p}: cannot be read ({type(e).__name__}); give a readable TOML file") from None
    return parse_scene(text, p)


def parse_scene(text: str, p: Path) -> SceneFile:
    """The scene file whose text is `text` (`p`: its path, the name messages give it and the
    scene's default name), every key checked, as `read_scene` reads it."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"scene {p}: not TOML ({e}); see docs/SCENES.md for the format") from None
    r = _Reader(p)
    r.table(data, "", TOP, ("format", "target", "goal"))
    if data["format"] != FORMAT:
        raise r.fail("format", f'this lmjx reads "{FORMAT}", got {data["format"]!r}')
    name = r.text(data, "name", p.stem).strip()
    if not name:
        raise r.fail("name", "give a name that is not empty")
    number = 0
    if "number" in data:
        number = data["number"]
        if isinstance(number, bool) or not isinstance(number, int) or not 1 <= number <= 99:
            raise r.fail("number", f"give a whole number 1 to 99, got {number!r}")
    budget = data.get("budget", 30)
    if isinstance(budget, bool) or not isinstance(budget, int) or not 1 <= budget <= 10_000:
        raise r.fail("budget", f"give a whole number 1 to 10000, got {budget!r}")
    scale = data.get("scale_with_robot", False)
    if not isinstance(scale, bool):
        raise r.fail("scale_with_robot", f"give true or false, got {scale!r}")
    task_set = r.word(data, "task_set", "", CUSTOM)
    table = r.table(data.get("table", {}), "table", TABLE)
    jitter = r.table(data.get("jitter", {}), "jitter", JITTER)
    target = r.box(data["target"], "target", MOVABLE, "target", True, TARGET_RGBA)
    boxes: list[Box] = []
    for kind, keys, movable, rgba in (("obstacles", OBSTACLE, True, OBSTACLE_RGBA), ("fixed", FIXED, False,
                                                                                        FIXED_RGBA)):  # fmt: skip
        items = data.get(kind, [])
        if not isinstance(items, list):
            raise r.fail(kind, f"must be an array of tables: write each as [[{kind}]]")
        for i, item in enumerate(items, 1):
            where = f"{kind}[{i}]"
            default = f"{'obstacle' if movable else 'fixed'}{i}"
            boxes.append(r.box(item, where, keys, r.word(item if isinstance(item, dict) else {}, "name", where,
                                                         default), movable, rgba))  # fmt: skip
    seen: set[str] = set()
    for b in boxes:
        if b.name in RESERVED or b.name in seen:
            why = "is the name of another part of the scene" if b.name in RESERVED else "is given twice"
            raise r.fail("", f"the name '{b.name}' {why}; give each obstacle a name of its own")
        seen.add(b.name)
    goal = r.table(data["goal"], "goal", GOAL, ("size",))
    half = tuple(s / 2 for s in r.vector(goal, "size", "goal", 2, 0.0, 5.0, above=True))
    if ("center" in goal) == ("distance" in goal or "angle" in goal):
        raise r.fail("goal", "give either center = [x, y] or distance and angle (from the target's position)")
    if "center" in goal:
        center = r.vector(goal, "center", "goal", 2, -10.0, 10.0)
    else:
        if not ("distance" in goal and "angle" in goal):
            raise r.fail("goal", "give both distance and angle (or center = [x, y])")
        dist = r.number(goal, "distance", "goal", None, 0.0, 10.0)
        a = math.radians(r.number(goal, "angle", "goal", None, -360.0, 360.0))
        center = (target.x + dist * math.cos(a), target.y + dist * math.sin(a))  # as `paper_variant` places goals
    sc = Scenario(
        number,
        r.text(data, "title", name),
        r.text(data, "description", ""),
        target,
        tuple(b for b in boxes if b.movable),
        fixed=tuple(b for b in boxes if not b.movable),
        goal_center=center,
        goal_half=half,
        jitter=r.number(jitter, "position", "jitter", 0.02, 0.0, 0.5),
        yaw_jitter=r.number(jitter, "yaw", "jitter", 0.26, 0.0, math.pi),
        tasks=task_set,
        budget=budget,
        table_friction=r.number(table, "friction", "table", 0.5, 0.0, 10.0, above=True),
    )
    return SceneFile(p, sc, name, scale, text)


def load_scene(path: str | Path, robot: Robot | str | Path | None = None, map_file: MapFile | None = None) -> Task:
    """The task a scene file describes, placed for `robot` (a Robot, a shipped robot's name
    or an MJCF's path; default: `map_file`'s robot, else the Panda), its geometry checked
    before anything is simulated (`lmjx.sim.scenecheck.check_geometry`): objects apart, on
    the table and clear of the arm's base; with `map_file` (a `MapFile`), also that the map
    reaches the goal region (`check_goal`).  A mistake is one `SceneError` line.

    >>> import lmjx
    >>> task = lmjx.load_scene(lmjx.shipped_scene(1, "paper"))
    >>> task.name, task.budget, len(task.scenario.obstacles)
    ('scenario 1', 30, 3)
    """
    from lmjx.model.robot import as_robot
    from lmjx.sim.scenecheck import check_geometry, check_goal

    rob = as_robot(robot if robot is not None or map_file is None else map_file.robot)
    scene = read_scene(path)
    task = scene.task(rob)
    check_geometry(task, rob, f"scene {scene.path}")
    if map_file is not None:
        if map_file.reach is None:
            raise SceneError(f"scene {scene.path}: the map {map_file.path} has no reach map to check the goal against")
        check_goal(task, map_file.reach, f"scene {scene.path}")
    return task


def shipped_scene(number: int, tasks: str = "paper") -> Path:
    """The file of the shipped scenario `number` (1, 2, 3) of the task set `tasks` ("paper"
    or "hard"): the same task as `lmjx plan --scenario N --tasks T` (tests/test_scenes.py)."""
    if number not in (1, 2, 3) or tasks not in TASK_SETS:
        raise SceneError(f"no shipped scene {number!r} of the task set {tasks!r}; use 1, 2 or 3 and paper or hard")
    return SCENES_DIR / f"scenario{number}_{tasks}.toml"


def _num(v: float) -> str:
    """A float as TOML reads it back exactly (Python's shortest round-trip form)."""
    return repr(float(v))


def _vec(values) -> str:
    return "[" + ", ".join(_num(v) for v in values) + "]"


def _box_lines(b: Box, movable_keys: bool, default_rgba: tuple, name: bool) -> list[str]:
    lines = [f"name = {json.dumps(b.name)}"] if name else []
    if b.shape == "box":
        lines.append(f"size = {_vec(2 * h for h in b.half)}")
    else:  # (2 x and / 2 are exact: the radius and height read back to the bit)
        lines += [f"shape = {json.dumps(b.shape)}", f"radius = {_num(b.half[0])}", f"height = {_num(2 * b.half[2])}"]
    lines.append(f"position = {_vec((b.x, b.y))}")
    if b.yaw:
        lines.append(f"yaw = {_num(b.yaw)}")
    if movable_keys:
        lines.append(f"mass = {_num(b.mass)}")
        lines += [f"{k} = {_num(getattr(b, k))}" for k in ("jitter", "yaw_jitter") if getattr(b, k) is not None]
    elif b.z is not None:
        lines.append(f"z = {_num(b.z)}")
    if b.friction != 0.5:
        lines.append(f"friction = {_num(b.friction)}")
    if tuple(b.rgba) != default_rgba:
        lines.append(f"color = {_vec(b.rgba)}")
    return lines


def scene_text(sc: Scenario, name: str, scale_with_robot: bool = False, header: str = "") -> str:
    """`sc` as a scene file (read back by `read_scene`, every float exactly); `header`:
    comment lines to put first."""
    out = [f"# {line}" if line else "#" for line in header.splitlines()]
    out += [f'format = "{FORMAT}"', f"name = {json.dumps(name)}", f"title = {json.dumps(sc.title)}",
            f"description = {json.dumps(sc.description)}"]  # fmt: skip
    if sc.number:
        out.append(f"number = {sc.number}")
    out += [f"task_set = {json.dumps(sc.tasks)}", f"budget = {sc.budget}"]
    if scale_with_robot:
        out.append("scale_with_robot = true")
    out += ["", "[table]", f"friction = {_num(sc.table_friction)}"]
    out += ["", "[jitter]", f"position = {_num(sc.jitter)}", f"yaw = {_num(sc.yaw_jitter)}"]
    out += ["", "[target]", *_box_lines(sc.target, True, TARGET_RGBA, name=False)]
    for b in sc.obstacles:
        out += ["", "[[obstacles]]", *_box_lines(b, True, OBSTACLE_RGBA, name=True)]
    for b in sc.fixed:
        out += ["", "[[fixed]]", *_box_lines(b, False, FIXED_RGBA, name=True)]
    out += ["", "[goal]", f"center = {_vec(sc.goal_center)}", f"size = {_vec(2 * h for h in sc.goal_half)}", ""]
    return "\n".join(out)


# ------------------------------------------------------------------------------ a trial's record of its scene


def definitions_digest(scenarios: Iterable[Scenario]) -> str:
    """A digest of scenarios' definitions as trials face them (every object, obstacle, goal
    region, jitter and budget, placed for the robot): SHA-256 of their fields
    (`dataclasses.asdict`, keyed by their numbers) as JSON with sorted keys, its first 16 hex
    digits.  The same definition gives the same digest whether it was resolved from a shipped
    scenario or read from a file."""
    defs = {str(sc.number): asdict(sc) for sc in scenarios}
    return hashlib.sha256(json.dumps(defs, sort_keys=True).encode()).hexdigest()[:16]


def scene_digest(task: Task) -> str:
    """The digest of one task's definition (`definitions_digest`)."""
    return definitions_digest([task.scenario])


def is_shipped(task: Task, robot: Robot) -> bool:
    """Whether `task` is a shipped scenario of a task set, placed for `robot`, definition and all."""
    if task.number not in SCENARIOS or task.tasks not in TASK_SETS or task.robot != robot.key:
        return False
    return resolve_task(task.number, robot, task.tasks).scenario == task.scenario


def scene_record(task: Task, robot: Robot) -> dict:
    """What a trial's record keeps of its scene, enough to rebuild the task (`record_task`):
    a shipped scenario (`is_shipped`) as its number and task set; any other task as the text
    of its scene file (a `SceneTask`'s as read, else the one `scene_text` writes of it), its
    name, its file and its number; both with `scene_digest`."""
    digest = scene_digest(task)
    if is_shipped(task, robot):
        return {"kind": "shipped", "scenario": task.number, "tasks": task.tasks, "digest": digest}
    if isinstance(task, SceneTask) and task.text:
        text, file = task.text, task.file or None
    else:
        text, file = scene_text(task.scenario, task.name), None
    return {"kind": "scene", "name": task.name, "file": file, "number": task.number, "text": text, "digest": digest}


def record_task(scene: object, robot: Robot, where: str) -> tuple[Task, bool]:
    """The task a record's scene (`scene_record`) describes, placed for `robot`, and whether
    its definition has the digest the record gives (False: the record was made by another
    version of lmjx, or edited).  Its geometry is not checked again: the trial ran on it.  A
    scene that cannot be read is a one-line ConfigError or SceneError starting with `where`."""
    if not isinstance(scene, dict) or scene.get("kind") not in ("shipped", "scene"):
        raise ConfigError(f"{where}: its record of the scene is not one lmjx writes; plan the trial again with "
                          "lmjx plan --json or lmjx evaluate")  # fmt: skip
    if scene["kind"] == "shipped":
        n, tasks = scene.get("scenario"), scene.get("tasks")
        if n not in SCENARIOS or tasks not in TASK_SETS:
            raise ConfigError(f"{where}: its scene names scenario {n!r} of the task set {tasks!r}, which this lmjx "
                              "does not ship; view it with the lmjx that ran it")  # fmt: skip
        task = resolve_task(int(n), robot, str(tasks))
    else:
        text, name = scene.get("text"), str(scene.get("name") or "scene")
        if not isinstance(text, str):
            raise ConfigError(f"{where}: its scene lacks the scene file's text; plan the trial again with lmjx plan "
                              "--json or lmjx evaluate")  # fmt: skip
        path = Path(str(scene.get("file") or f"{name}.toml"))
        try:
            task = parse_scene(text, path).task(robot)
        except SceneError as e:
            raise SceneError(f"{where}: its scene cannot be read ({e})") from None
        number = scene.get("number")
        if isinstance(number, int) and number and not task.number:  # numbered by `lmjx evaluate --scenes`
            task = replace(task, scenario=replace(task.scenario, number=number))
    return task, scene_digest(task) == scene.get("digest")
