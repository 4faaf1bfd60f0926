"""The three evaluation scenarios of the paper (Section IV), as data.

All take place on the robot's table in front of it, inside the area that both failure cases
can reach (see the Reach-Ability maps): a yellow 5 cm target cube must end in a green goal
region.
  1. the target and 3 movable obstacles that crowd it;
  2. a fixed tunnel partitioning the table: the target must pass through it;
  3. the target and 11 movable obstacles (many object-object interactions).
Two task sets share these layouts (`TASK_SETS`), both frozen (tests/test_frozen_tasks.py pins
their geometry and layouts):
  * "hard": the goals as first built here, 22-28 cm from the target, 12 cm square, a
    budget of 30 actions: tasks where choosing actions by simulation matters;
  * "paper": the goal regions, distances and budget chosen by calibration to reproduce the
    paper's reported outcomes (its Random ASM completes a large share of the tasks, some in
    one action), with Random only, on calibration seeds the evaluation never uses
    (`PAPER_TASKS`; the rule: docs/EVALUATION.md, "Deviations from the paper").
    In scenarios 1 and 3 the goal's direction from the target is calibrated too (the hard
    tasks' lies against the way pushes from this arm tend to move the target);
    in scenario 2 the task is reversed: the target starts where the hard task's goal is, on
    the robot's side, and is pushed through the tunnel to a goal on the far side (pulling
    it back, the hard task, leaves an arm that never touches the tunnel 2-3 feasible actions
    on a 100,000-edge map; pushing it away, 16-20: docs/EVALUATION.md).
The layouts are the Panda's; `scenario(n, scale)` scales every position on the table (and the
tunnel's length) about the robot's base by the robot's `task_scale` (`placed`), so that the
same three scenarios sit at the same place in the reach of an arm of another size (objects
keep their sizes).  `sample_layout` varies the movable objects' initial poses per trial
(seeded): each is moved uniformly within +-`jitter` m and turned within +-`yaw_jitter` rad of
its nominal pose (the scenario's, or the object's own), keeping objects apart (a box's
footprint a rectangle, an upright cylinder's, `Cylinder`, a circle: `lmjx.sim.footprint`).
`resolve_task` makes a scenario of a task set, placed for a robot, a `Task`: the value the
entry points make once and every stage below them takes; a scene file makes the same value
(`lmjx.sim.scenefile`: the three scenarios of both task sets ship as files).  Nothing here
simulates; `lmjx.sim.scene` builds the MuJoCo models.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from lmjx.errors import ConfigError, SceneError
from lmjx.sim.footprint import footprints_overlap

if TYPE_CHECKING:
    from lmjx.model.robot import Robot

CUBE = (0.025, 0.025, 0.025)
TARGET_RGBA = (1.0, 0.8, 0.05, 1.0)
OBSTACLE_RGBA = (0.93, 0.93, 0.9, 1.0)
FIXED_RGBA = (0.45, 0.45, 0.5, 1.0)
GOAL_RGBA = (0.1, 0.8, 0.2, 0.45)


@dataclass(frozen=True)
class Box:
    """A box on the table: half extents, nominal pose of its centre (x, y, yaw), mass.  An
    upright cylinder is a `Cylinder`, a Box of its own shape (`shape`)."""

    name: str
    half: tuple[float, float, float]
    x: float
    y: float
    yaw: float = 0.0
    mass: float = 0.1  # [kg]
    movable: bool = True
    rgba: tuple[float, float, float, float] = OBSTACLE_RGBA
    z: float | None = None  # centre height; default: resting on the table
    # (the fields below are left out of the repr: it keys the push counts a map stores,
    # `lmjx.mapfile.pushmap.counts_key`, which frictions and jitters do not change)
    friction: float = field(default=0.5, repr=False)  # sliding friction (MuJoCo takes the larger of a pair's)
    jitter: float | None = field(default=None, repr=False)  # [m] its own position jitter; None: the scenario's
    yaw_jitter: float | None = field(default=None, repr=False)  # [rad] its own yaw jitter; None: the scenario's
    shape: ClassVar[str] = "box"  # (a class value: no field, so a box's repr, equality and asdict hold no shape)

    @property
    def zc(self) -> float:
        return self.half[2] if self.z is None else self.z

    @property
    def footprint_radius(self) -> float:
        """[m] the radius of the smallest circle about its centre that holds its footprint
        at any yaw (a box's half diagonal, a cylinder's radius)."""
        return math.hypot(self.half[0], self.half[1])


@dataclass(frozen=True)
class Cylinder(Box):
    """An upright cylinder on the table (its axis along z): `half` is (radius, radius, half
    height), the half sizes of its circumscribing box, and its yaw turns that box (the
    cylinder itself looks the same at any yaw).  Where a check takes boxes only, the
    circumscribing box stands for it (conservative: it holds the cylinder).  Its `shape`
    is a field: its repr, equality and `asdict` tell it from a box of the same half sizes."""

    shape: str = field(default="cylinder", init=False)  # type: ignore[misc]

    def __post_init__(self) -> None:
        if self.half[0] != self.half[1]:
            raise SceneError(f"cylinder '{self.name}': half is (radius, radius, half height), got {self.half}")

    @property
    def radius(self) -> float:
        return self.half[0]

    @property
    def height(self) -> float:
        return 2 * self.half[2]

    @property
    def footprint_radius(self) -> float:
        return self.half[0]


@dataclass(frozen=True)
class Scenario:
    number: int
    title: str
    description: str
    target: Box
    obstacles: tuple[Box, ...]  # movable
    fixed: tuple[Box, ...] = ()  # static (tunnel)
    goal_center: tuple[float, float] = (0.45, -0.2)
    goal_half: tuple[float, float] = (0.06, 0.06)
    jitter: float = 0.02  # [m]
    yaw_jitter: float = 0.26  # [rad]
    tasks: str = "hard"  # the task set it belongs to
    budget: int = 30  # the task set's action budget (a planner's default max_actions)
    table_friction: float = field(default=0.5, repr=False)  # sliding friction of the table top (out of the repr: Box's)

    @property
    def movable(self) -> tuple[Box, ...]:
        """Target first, then the movable obstacles."""
        return (self.target, *self.obstacles)


@dataclass
class Layout:
    """Initial poses of a scenario's movable objects for one trial (target first), what
    `Executor.reset` sets up: `Task.layout(seed)` draws them, and `Layout(task.scenario, seed,
    poses)` gives poses of one's own ((n, 3) x, y [m] on the table, yaw [rad], the objects in
    the order of `scenario.movable`); poses of another shape are a one-line SceneError."""

    scenario: Scenario
    seed: int
    poses: np.ndarray = field(repr=False)  # (n, 3) x, y, yaw

    def __post_init__(self) -> None:
        if not isinstance(self.scenario, Scenario):
            raise SceneError(f"Layout: scenario is a task's (task.scenario), got {type(self.scenario).__name__}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int | np.integer):
            raise SceneError(f"Layout: seed is a whole number, got {self.seed!r}")
        names = ", ".join(b.name for b in self.scenario.movable)
        try:
            poses = np.asarray(self.poses, np.float64)
        except (TypeError, ValueError):
            poses = np.zeros(0)
        if poses.shape != (len(self.scenario.movable), 3) or not np.isfinite(poses).all():
            got = getattr(self.poses, "shape", type(self.poses).__name__)
            n = len(self.scenario.movable)
            raise SceneError(f"Layout: poses are ({n}, 3) finite x, y, yaw of {names}, got {got}")
        self.poses = poses


def _target(x: float, y: float) -> Box:
    return Box("target", CUBE, x, y, mass=0.1, rgba=TARGET_RGBA)


# The task area: the table to the robot's left front, which both failure cases reach
# (case 1 cannot reach a wedge to the right of the robot's centre line; see its map).
GOAL = (0.46, 0.14)


def _scenario1() -> Scenario:
    t = (0.40, 0.42)
    return Scenario(
        1,
        "clutter around the target",
        "The target cube with three movable boxes crowding it on three sides; the goal lies "
        "28 cm away toward the robot's centre line.",
        _target(*t),
        (
            Box("obstacle1", (0.03, 0.03, 0.03), t[0] + 0.075, t[1] + 0.01, mass=0.15),
            Box("obstacle2", (0.025, 0.04, 0.03), t[0] - 0.07, t[1] + 0.02, mass=0.15),
            Box("obstacle3", (0.04, 0.025, 0.03), t[0] + 0.01, t[1] + 0.08, mass=0.15),
        ),
        goal_center=GOAL,
    )


def _scenario2() -> Scenario:
    # A wall along x at y = 0.26 with one opening, roofed: a tunnel the cube and the hand fit
    # through, the rest of the arm not; the goal lies just past its exit.
    y_wall, half_t = 0.26, 0.005  # 1 cm thick
    wall_h = 0.14  # half height: 28 cm tall
    gap_lo, gap_hi = 0.29, 0.65  # the opening along x: 36 cm
    roof_z = 0.25  # underside of the roof
    walls = (
        Box("wall_near", ((gap_lo - 0.12) / 2, half_t, wall_h), (0.12 + gap_lo) / 2, y_wall, movable=False,
            rgba=FIXED_RGBA),
        Box("wall_far", ((0.86 - gap_hi) / 2, half_t, wall_h), (gap_hi + 0.86) / 2, y_wall, movable=False,
            rgba=FIXED_RGBA),
        Box("roof", ((gap_hi - gap_lo) / 2, half_t, 0.015), (gap_lo + gap_hi) / 2, y_wall, movable=False,
            rgba=FIXED_RGBA, z=roof_z + 0.015),
    )  # fmt: skip
    return Scenario(
        2,
        "tunnel",
        "A fixed wall 74 cm long across the table in front of the robot with a roofed opening (a "
        "tunnel 36 cm wide and 25 cm high through a 1 cm wall): the target starts on the far side; "
        "the goal region begins at the tunnel's exit on the near side.",
        _target(0.47, 0.40),
        (),
        fixed=walls,
        goal_center=(0.47, 0.18),
    )


def _scenario3() -> Scenario:
    t = (0.40, 0.44)
    spots = [
        (0.31, 0.50), (0.40, 0.535), (0.50, 0.50), (0.31, 0.39), (0.50, 0.40), (0.35, 0.31),
        (0.46, 0.30), (0.57, 0.31), (0.30, 0.22), (0.58, 0.21), (0.38, 0.10),
    ]  # fmt: skip
    sizes = [(0.025, 0.025, 0.025), (0.03, 0.02, 0.025), (0.02, 0.03, 0.025)]
    obstacles = tuple(
        Box(f"obstacle{i + 1}", sizes[i % 3], x, y, yaw=0.4 * (i % 4), mass=0.08) for i, (x, y) in enumerate(spots)
    )
    return Scenario(
        3,
        "eleven obstacles",
        "The target cube among eleven movable boxes scattered around it and between it and the goal.",
        _target(*t),
        obstacles,
        goal_center=GOAL,
    )


SCENARIOS = {1: _scenario1, 2: _scenario2, 3: _scenario3}
TASK_SETS = ("paper", "hard")


@dataclass(frozen=True)
class PaperTask:
    """A scenario's task in the paper set: a goal square of half size `half`, centred `distance`
    metres from the target's nominal start in the direction `angle` (degrees on the table,
    counter-clockwise from the robot's x axis)."""

    distance: float  # [m]
    half: float  # [m]
    angle: float  # [deg]


# Chosen by calibration (Random only, calibration seeds; docs/EVALUATION.md, "Deviations from the
# paper"); never tuned on the evaluation's seeds; frozen (tests/test_frozen_tasks.py).
PAPER_TASKS = {1: PaperTask(0.15, 0.08, 90.0), 2: PaperTask(0.17, 0.08, 90.0), 3: PaperTask(0.13, 0.08, 0.0)}
PAPER_BUDGET = 30


def paper_variant(sc: Scenario, task: PaperTask, budget: int) -> Scenario:
    """A hard scenario turned into a paper-set task: the same objects, the goal `task.distance`
    from the target's start in the direction `task.angle`; in the tunnel the target starts
    where the hard task's goal is, on the robot's side, and is pushed through the tunnel."""
    target = sc.target
    if sc.fixed:
        target = replace(sc.target, x=float(sc.goal_center[0]), y=float(sc.goal_center[1]))
    a = math.radians(task.angle)
    x, y = target.x + task.distance * math.cos(a), target.y + task.distance * math.sin(a)
    size = f"a {2 * task.half * 100:.0f} cm square"
    if sc.fixed:
        desc = (f"The tunnel of the hard task, crossed the other way: the target starts on the robot's side; the "
                f"goal region ({size}, centred {task.distance * 100:.0f} cm from the target) lies past the tunnel "
                "on the far side.")  # fmt: skip
    else:
        desc = (f"The objects of the hard task; the goal region ({size}) is centred {task.distance * 100:.0f} cm from "
                f"the target at {task.angle:.0f} deg.")  # fmt: skip
    return replace(sc, target=target, goal_center=(x, y), goal_half=(task.half, task.half), tasks="paper",
                   budget=budget, description=desc)  # fmt: skip


def scenario(number: int, scale: float = 1.0, tasks: str = "paper") -> Scenario:
    """Scenario `number` (1, 2, 3) of the task set `tasks` ("paper" or "hard"), with its table
    positions scaled by `scale` about the robot's base (a robot's `profile.task_scale`; 1
    for the Panda)."""
    if number not in SCENARIOS:
        raise ConfigError(f"scenario {number!r} does not exist; use 1 (clutter), 2 (tunnel) or 3 (eleven boxes)")
    if tasks not in TASK_SETS:
        raise ConfigError(f"unknown task set '{tasks}'; use paper or hard")
    if not (math.isfinite(scale) and 0.2 <= scale <= 5.0):
        raise ConfigError(f"scenario scale {scale:g} is out of range (0.2 to 5)")
    sc = SCENARIOS[number]()
    if tasks == "paper":
        sc = paper_variant(sc, PAPER_TASKS[number], PAPER_BUDGET)
    return placed(sc, scale)


def placed(sc: Scenario, scale: float) -> Scenario:
    """`sc` with its table positions (the objects', the goal's) scaled by `scale` about the
    robot's base, and its fixed walls' lengths with them (their thickness kept; a fixed
    cylinder keeps its radius); objects keep their sizes.  `sc` itself where `scale` is 1."""
    if scale == 1.0:
        return sc

    def moved(b: Box) -> Box:
        return replace(b, x=b.x * scale, y=b.y * scale)

    def stretched(b: Box) -> Box:  # a fixed wall keeps its thickness, its length scales
        if b.shape != "box":
            return moved(b)  # a cylinder (a post) keeps its radius
        hx, hy, hz = b.half
        half = (hx * scale, hy, hz) if hx >= hy else (hx, hy * scale, hz)
        return replace(moved(b), half=half)

    return replace(
        sc,
        target=moved(sc.target),
        obstacles=tuple(moved(b) for b in sc.obstacles),
        fixed=tuple(stretched(b) for b in sc.fixed),
        goal_center=(sc.goal_center[0] * scale, sc.goal_center[1] * scale),
    )


@dataclass(frozen=True)
class Task:
    """A task resolved once for one robot (`resolve_task`): what is on the table and where the
    target must go (`scenario`: the target, the movable and fixed obstacles, the goal region,
    placed for the robot, and the action budget), the robot it is placed for, and what the task
    is called.  The entry points (`lmjx.plan_task`, `lmjx evaluate`) make one; the stages below
    them take it, or its `scenario`, never a scenario's number."""

    scenario: Scenario
    robot: str  # the key of the robot the positions are placed for (`Robot.key`)
    name: str  # how messages call it ("scenario 1")

    @property
    def number(self) -> int:
        """The shipped scenario's number (1, 2, 3), as results record it."""
        return self.scenario.number

    @property
    def tasks(self) -> str:
        """The task set it belongs to ("paper" or "hard")."""
        return self.scenario.tasks

    @property
    def budget(self) -> int:
        """The task's action budget (a planner's default max_actions)."""
        return self.scenario.budget

    def layout(self, seed: int) -> Layout:
        """The objects' initial poses for a trial seed (`sample_layout`)."""
        return sample_layout(self.scenario, seed)

    def in_goal(self, xy: np.ndarray, margin: float = 0.0) -> bool:
        """Whether a point (the target's centre) lies in the goal region, `margin` inside."""
        return in_goal(self.scenario, xy, margin)


def resolve_task(number: int, robot: Robot, tasks: str = "paper") -> Task:
    """Scenario `number` (1, 2, 3) of the task set `tasks` ("paper" or "hard"), placed for
    `robot` (its table positions scaled by the robot's `profile.task_scale`)."""
    return Task(scenario(number, robot.profile.task_scale, tasks), robot.key, f"scenario {number}")


def _corners(half: tuple[float, float, float], x: float, y: float, yaw: float, grow: float) -> np.ndarray:
    hx, hy = half[0] + grow, half[1] + grow
    c, s = math.cos(yaw), math.sin(yaw)
    local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
    return local @ np.array([[c, s], [-s, c]]) + [x, y]


def _overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two convex polygons (4, 2) overlap (separating axis test)."""
    for poly in (a, b):
        for i in range(4):
            edge = poly[(i + 1) % 4] - poly[i]
            axis = np.array([-edge[1], edge[0]])
            pa, pb = a @ axis, b @ axis
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


def sample_layout(sc: Scenario, seed: int, tries: int = 200) -> Layout:
    """Seeded initial poses: each movable object jittered around its nominal pose (by its own
    jitter where it has one, else the scenario's), without overlaps with the other objects and
    the fixed ones; drawn again, up to `tries` times, until none overlap."""
    rng = np.random.default_rng(seed)
    boxes = sc.movable
    # per object (the same draws as one scalar jitter for all: numpy broadcasts the bounds)
    jit = np.array([sc.jitter if b.jitter is None else b.jitter for b in boxes])[:, None]
    yaw_jit = np.array([sc.yaw_jitter if b.yaw_jitter is None else b.yaw_jitter for b in boxes])
    for _ in range(tries):
        d = rng.uniform(-jit, jit, (len(boxes), 2))
        yaw = rng.uniform(-yaw_jit, yaw_jit, len(boxes))
        poses = np.array([[b.x + dx, b.y + dy, b.yaw + w] for b, (dx, dy), w in zip(boxes, d, yaw, strict=True)])
        if _separated(boxes, poses, sc.fixed):
            return Layout(sc, seed, poses)
    raise ConfigError(
        f"{sc.title}: could not place the objects apart in {tries} draws (seed {seed}); move them apart or lower "
        "their jitter"
    )


def _separated(boxes: tuple[Box, ...], poses: np.ndarray, fixed: tuple[Box, ...], gap: float = 0.004) -> bool:
    """No two footprints (grown by gap / 2 each) overlap, nor any with a fixed obstacle on the
    table (boxes as rectangles, cylinders as circles: `lmjx.sim.footprint`)."""
    polys = [_corners(b.half, *p, gap / 2) for b, p in zip(boxes, poses, strict=True)]
    for i, a in enumerate(boxes):
        for j in range(i + 1, len(boxes)):
            b = boxes[j]
            if a.shape == b.shape == "box":
                hit = _overlap(polys[i], polys[j])
            else:
                hit = bool(footprints_overlap(a, poses[i], b, poses[j], gap / 2))
            if hit:
                return False
        for f in fixed:
            if f.zc - f.half[2] > a.half[2] * 2:
                continue  # above the object (the roof)
            if a.shape == f.shape == "box":
                hit = _overlap(polys[i], _corners(f.half, f.x, f.y, f.yaw, gap / 2))
            else:
                hit = bool(footprints_overlap(a, poses[i], f, np.array([f.x, f.y, f.yaw]), gap / 2))
            if hit:
                return False
    return True


def in_goal(sc: Scenario, xy: np.ndarray, margin: float = 0.0) -> bool:
    """Whether a point (the target's centre) lies in the goal region, at least `margin` inside."""
    return bool(
        abs(xy[0] - sc.goal_center[0]) <= sc.goal_half[0] - margin
        and abs(xy[1] - sc.goal_center[1]) <= sc.goal_half[1] - margin
    )
