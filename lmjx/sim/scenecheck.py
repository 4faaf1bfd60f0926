"""Whether a scene can be set up, checked before anything is simulated: a one-line
`SceneError` for the first thing wrong.

Boxes' footprints are rectangles, upright cylinders' circles (`lmjx.sim.footprint`: every
test below is exact for both shapes).
`check_geometry` (needs the robot): every name free in the robot's model; the movable boxes
apart from each other and from the fixed obstacles at their nominal poses (footprints grown
by half the gap `sample_layout` keeps), and apart in enough of the poses their jitter draws
(`JITTER_DRAWS` seeded draws, of which at least `MIN_APART` must be: a trial's layout is
drawn until none overlap, `sample_layout`'s 200 tries); every movable box on the table top
at its nominal pose grown by its position jitter, every fixed obstacle's footprint on it, and
the goal region on it; somewhere in the goal region for the target to rest, clear of the
fixed obstacles it cannot pass under (`GOAL_POINTS` points tried); no movable box and no
fixed obstacle through the arm's base (its parts welded to the world: C MuJoCo's distance
between their geoms and the box or cylinder geom, and the base's origin under the object).
`check_goal` (needs a map): a reachable cell (NPM or PM, smoothed labels) under the goal
region.  Nothing here simulates.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from lmjx.errors import SceneError
from lmjx.sim.footprint import circle_inside, footprints_overlap, rect_corners, rect_distance, rect_rect
from lmjx.sim.scenarios import Box, Task

if TYPE_CHECKING:
    from lmjx.model.robot import Robot
    from lmjx.reach.reachability import ReachResult

GAP = 0.004  # [m] `sample_layout`'s gap between footprints
JITTER_DRAWS = 200  # poses drawn to check that the jitter leaves room
MIN_APART = 10  # of which at least this many must be apart (5 %: 200 tries fail with odds under 4e-5)
BASE_HEIGHT = 0.05  # [m] a fixed obstacle whose underside is lower than this over the base's origin blocks it
GOAL_POINTS = 41  # points along each side of the goal region where the target's centre is tried
EDGE_TOL = 1e-9  # [m] a footprint flush with the table's edge is on the table


def _inside(poly: np.ndarray, point: np.ndarray) -> bool:
    """Whether a point (2,) lies in a convex quadrilateral (4, 2) given counter-clockwise or
    clockwise."""
    edges = np.roll(poly, -1, axis=0) - poly
    rel = point[None] - poly
    cross = edges[:, 0] * rel[:, 1] - edges[:, 1] * rel[:, 0]
    return bool((cross >= 0).all() or (cross <= 0).all())


def _pairs_overlapping(movable: tuple[Box, ...], poses: np.ndarray, fixed: tuple[Box, ...]) -> np.ndarray:
    """(draws, pairs) which pairs overlap in each of the poses (draws, n, 3): movable pairs
    (i < j), then (movable, fixed) pairs, as `sample_layout` tests them (a fixed obstacle
    higher than twice a box's half height, the tunnel's roof, is above it; boxes as
    rectangles, cylinders as circles: `lmjx.sim.footprint`)."""
    half = np.array([b.half for b in movable])
    polys = rect_corners(half[None], poses, GAP / 2)  # (D, n, 4, 2)
    out = []
    for i in range(len(movable)):
        for j in range(i + 1, len(movable)):
            if movable[i].shape == movable[j].shape == "box":
                out.append(rect_rect(polys[:, i], polys[:, j]))
            else:
                out.append(footprints_overlap(movable[i], poses[:, i], movable[j], poses[:, j], GAP / 2))
    for f in fixed:
        pose = np.array([f.x, f.y, f.yaw])
        fp = rect_corners(np.array(f.half), pose, GAP / 2)
        for i, b in enumerate(movable):
            if f.zc - f.half[2] > b.half[2] * 2:
                out.append(np.zeros(len(poses), bool))
            elif b.shape == f.shape == "box":
                out.append(rect_rect(polys[:, i], np.broadcast_to(fp, polys[:, i].shape)))
            else:
                out.append(footprints_overlap(b, poses[:, i], f, np.broadcast_to(pose, poses[:, i].shape), GAP / 2))
    return np.stack(out, 1) if out else np.zeros((len(poses), 0), bool)


def _pair_names(movable: tuple[Box, ...], fixed: tuple[Box, ...]) -> list[tuple[str, str]]:
    names = [(a.name, b.name) for i, a in enumerate(movable) for b in movable[i + 1 :]]
    return names + [(b.name, f.name) for f in fixed for b in movable]


def check_geometry(task: Task, robot: Robot, where: str) -> None:
    """Refuse (`SceneError`, one line starting with `where`) a scene that cannot be set up
    for `robot` (module docstring)."""
    sc = task.scenario
    movable, fixed = sc.movable, sc.fixed
    m = robot.mj
    taken = {("body", m.body(i).name) for i in range(m.nbody)} | {("geom", m.geom(i).name) for i in range(m.ngeom)}
    taken |= {("joint", m.joint(i).name) for i in range(m.njnt)}
    for b in (*movable, *fixed):
        mine = {("body", b.name), ("geom", f"{b.name}_geom"), ("joint", f"{b.name}_free")} if b.movable else {
            ("geom", b.name)}  # fmt: skip
        if mine & taken:
            kind, name = sorted(mine & taken)[0]
            raise SceneError(f"{where}: the name '{b.name}' is taken: the robot's model has a {kind} '{name}'; "
                             "rename the object")  # fmt: skip
    nominal = np.array([[b.x, b.y, b.yaw] for b in movable])
    hit = _pairs_overlapping(movable, nominal[None], fixed)[0]
    if hit.any():
        a, b = _pair_names(movable, fixed)[int(np.argmax(hit))]
        raise SceneError(f"{where}: '{a}' and '{b}' overlap at their nominal poses (keeping {GAP * 1000:g} mm "
                         "apart); move them apart")  # fmt: skip
    jit = np.array([sc.jitter if b.jitter is None else b.jitter for b in movable])
    yaw_jit = np.array([sc.yaw_jitter if b.yaw_jitter is None else b.yaw_jitter for b in movable])
    if jit.any() or yaw_jit.any():
        rng = np.random.default_rng(20_000)  # the check's own draws (no trial's)
        draws = nominal[None] + np.concatenate(
            [rng.uniform(-1.0, 1.0, (JITTER_DRAWS, len(movable), 2)) * jit[None, :, None],
             rng.uniform(-1.0, 1.0, (JITTER_DRAWS, len(movable), 1)) * yaw_jit[None, :, None]], axis=2,
        )  # fmt: skip
        hits = _pairs_overlapping(movable, draws, fixed)
        apart = int((~hits.any(axis=1)).sum())
        if apart < MIN_APART:
            a, b = _pair_names(movable, fixed)[int(np.argmax(hits.sum(axis=0)))]
            raise SceneError(
                f"{where}: the objects' jitter leaves them apart in only {apart} of {JITTER_DRAWS} draws ('{a}' and "
                f"'{b}' overlap most); move them apart or lower their jitter"
            )
    lo = robot.arm.table_center[:2] - robot.arm.table_half[:2]
    hi = robot.arm.table_center[:2] + robot.arm.table_half[:2]
    for b, j in zip(movable, jit, strict=True):
        corners = _extent(b, float(j))
        if np.any(corners < lo) or np.any(corners > hi):
            raise SceneError(f"{where}: '{b.name}' at ({b.x:g}, {b.y:g}) is off the table (its top spans x "
                             f"{lo[0]:g} to {hi[0]:g}, y {lo[1]:g} to {hi[1]:g} m, jitter included); move it onto "
                             "the table")  # fmt: skip
    for f in fixed:
        corners = _extent(f, 0.0)
        if np.any(corners < lo - EDGE_TOL) or np.any(corners > hi + EDGE_TOL):
            raise SceneError(f"{where}: the fixed obstacle '{f.name}' at ({f.x:g}, {f.y:g}) reaches off the table "
                             f"(its top spans x {lo[0]:g} to {hi[0]:g}, y {lo[1]:g} to {hi[1]:g} m); move it onto the "
                             "table")  # fmt: skip
    g_lo = np.array(sc.goal_center) - np.array(sc.goal_half)
    g_hi = np.array(sc.goal_center) + np.array(sc.goal_half)
    if np.any(g_lo < lo) or np.any(g_hi > hi):
        raise SceneError(f"{where}: the goal region reaches off the table (its top spans x {lo[0]:g} to {hi[0]:g}, "
                         f"y {lo[1]:g} to {hi[1]:g} m); move the goal onto the table")  # fmt: skip
    covering = goal_cover(task)
    if covering:
        (gx, gy), names = sc.goal_center, " and ".join(f"'{f.name}'" for f in covering)
        raise SceneError(f"{where}: the goal region centred at ({gx:g}, {gy:g}) is covered by the fixed obstacle"
                         f"{'s' if len(covering) > 1 else ''} {names}: the target cannot rest anywhere in it; move "
                         "the goal or the obstacle")  # fmt: skip
    _check_base(task, robot, where)


def _extent(b: Box, jitter: float) -> np.ndarray:
    """Points (k, 2) whose bounding rectangle is that of everywhere `b`'s footprint reaches
    moved by up to `jitter` in x and y (and turned, by any yaw): a box's corners grown by
    jitter x sqrt(2) (at its nominal yaw), a cylinder's circle's extreme points, exactly."""
    if b.shape == "box":
        return rect_corners(np.array(b.half), np.array([b.x, b.y, b.yaw]), jitter * math.sqrt(2))
    r = b.half[0] + jitter
    return np.array([[b.x - r, b.y - r], [b.x + r, b.y + r]])


def goal_cover(task: Task) -> tuple[Box, ...]:
    """The fixed obstacles that leave the target no place in the goal region, most of the
    region first (empty where it has one).  The target's centre is tried at `GOAL_POINTS` x
    `GOAL_POINTS` points over the region, edges included (a centre on its edge is in it:
    `lmjx.sim.scenarios.in_goal`); a point is taken where the target, at any yaw, would overlap a fixed obstacle
    it cannot pass under (as `sample_layout` tells: one higher than the target is tall, the
    tunnel's roof, is above it): where the point lies closer to the obstacle's footprint than
    the target's smaller half side."""
    sc = task.scenario
    t = sc.target
    low = [f for f in sc.fixed if not f.zc - f.half[2] > t.half[2] * 2]
    if not low:
        return ()
    (cx, cy), (hx, hy) = sc.goal_center, sc.goal_half
    gx, gy = np.meshgrid(np.linspace(cx - hx, cx + hx, GOAL_POINTS), np.linspace(cy - hy, cy + hy, GOAL_POINTS))
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    reach = min(t.half[0], t.half[1])  # the target covers this disc about its centre at any yaw (a cylinder's own)
    taken = np.zeros((len(low), len(pts)), bool)
    for k, f in enumerate(low):
        if f.shape != "box":  # a cylinder: the distance to its circle
            taken[k] = np.hypot(pts[:, 0] - f.x, pts[:, 1] - f.y) - f.half[0] < reach
            continue
        taken[k] = rect_distance(pts, np.array(f.half), np.array([f.x, f.y, f.yaw])) < reach
    if not taken.any(axis=0).all():
        return ()
    order = np.argsort(-taken.sum(axis=1), kind="stable")
    return tuple(low[k] for k in order if taken[k].any())


def _check_base(task: Task, robot: Robot, where: str) -> None:
    """No movable box and no fixed obstacle through the parts of the arm welded to the world."""
    from lmjx.sim.scene import build_scene

    try:
        scene = build_scene(robot, task.scenario)
    except ValueError as e:  # MuJoCo's compiler: one line of its message
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        why = f"MuJoCo cannot build the scene ({first}); check the objects' names and sizes"
        raise SceneError(f"{where}: {why}") from None
    m = scene.model
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    robot_bodies = {robot.mj.body(i).name for i in range(1, robot.mj.nbody)}
    base = [g for g in range(m.ngeom) if m.body(int(m.geom_bodyid[g])).name in robot_bodies
            and m.body_weldid[m.geom_bodyid[g]] == 0]  # fmt: skip
    roots = [b for b in range(1, m.nbody) if m.body(b).name in robot_bodies and m.body_parentid[b] == 0]
    origins = [d.xpos[b] for b in roots]
    for b in (*task.scenario.movable, *task.scenario.fixed):
        g = m.geom(b.name if not b.movable else f"{b.name}_geom").id
        through = any(mujoco.mj_geomDistance(m, d, g, int(k), 0.01, None) < 0 for k in base)
        if not through and b.zc - b.half[2] < BASE_HEIGHT:  # reaching down to the table over the base's origin
            if b.shape == "box":
                poly = rect_corners(np.array(b.half), np.array([b.x, b.y, b.yaw]), 0.0)
                through = any(_inside(poly, o[:2]) for o in origins)
            else:
                through = any(circle_inside(o[:2], (b.x, b.y), b.half[0]) for o in origins)
        if through:
            kind = "movable box" if b.movable else "fixed obstacle"
            raise SceneError(f"{where}: the {kind} '{b.name}' at ({b.x:g}, {b.y:g}) passes through the arm's base; "
                             "move it away from the robot")  # fmt: skip


def check_goal(task: Task, reach: ReachResult, where: str) -> None:
    """Refuse a goal region with no reachable cell of the map under it (no NPM or PM cell of
    the smoothed labels whose square overlaps the region): the arm cannot act there."""
    from lmjx.reach.reachability import NPM

    sc = task.scenario
    cell = reach.config.cell
    (gx, gy), (hx, hy) = sc.goal_center, sc.goal_half
    ix = np.nonzero(np.abs(reach.xs - gx) < hx + cell / 2)[0]
    iy = np.nonzero(np.abs(reach.ys - gy) < hy + cell / 2)[0]
    if len(ix) and len(iy) and (reach.labels_smooth[np.ix_(iy, ix)] >= NPM).any():
        return
    raise SceneError(
        f"{where}: no reachable cell of the map (NPM or PM) lies under the goal region centred at ({gx:g}, {gy:g}); "
        "move the goal where the map reaches (lmjx reach --png shows where)"
    )
