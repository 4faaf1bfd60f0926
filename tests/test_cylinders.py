"""Upright cylinders in scene files (docs/SCENES.md, "Cylinders"): read and written back to the
bit, boxes as they were (repr, equality, asdict, the shipped sets' digests); one-line errors;
each geometry function against an independent reference (footprints against brute-force
points, the MuJoCo geom against C MuJoCo's distances and physics, the planner's clearance
against C MuJoCo's capsule-cylinder distance, the viewer's mesh against the solid); and a
hand-written scene with cylinders checked, planned by each ASM, evaluated, viewed and its
greedy action exported as a JointTrajectory.  Cheap: the planner tests' `plan_map`, one
action per trial, Greedy with 4 candidates."""

from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import cli, random_configs

import lmjx
from lmjx.errors import SceneError
from lmjx.sim.footprint import circle_circle, circle_rect, footprints_overlap, rect_corners, rect_distance
from lmjx.sim.scenarios import Box, Cylinder, Scenario, sample_layout
from lmjx.sim.scenefile import parse_scene, read_scene, scene_text

ROOT = Path(__file__).resolve().parent.parent
MUGS = ROOT / "examples" / "my_mugs.toml"
BASE = MUGS.read_text()
# the shipped task sets' digests (`task_digest`, Panda), as they were before cylinders existed
SHIPPED_DIGESTS = {"paper": "c9b92e26b6c1ad7d", "hard": "e6d3f9c94c1f2196"}
BRUTE_TOL = 2e-3  # [m] brute-force grids' spacing: cases closer than this to touching are not judged
KERNEL_TOL = 1e-5  # [m] the float32 clearance kernel against C MuJoCo's distance (measured: 1e-7)
DEPTH_TOL = 1e-4  # [m] ... against C MuJoCo's penetration depth (its EPA; measured: 3e-5)


def _edit(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


def test_a_cylinder_scene_reads_and_writes_back_and_boxes_stay_as_they_were(robot):
    from lmjx.evaluation.provenance import task_digest

    f = read_scene(MUGS)
    sc = f.scenario
    target, mug, book = sc.movable
    post = sc.fixed[0]
    assert isinstance(target, Cylinder) and target.shape == "cylinder" and target.half == (0.03, 0.03, 0.04)
    assert (target.radius, target.height, mug.radius, post.radius) == (0.03, 0.08, 0.04, 0.02)
    assert type(book) is Box and book.shape == "box" and post.zc == 0.15
    back = parse_scene(scene_text(sc, f.name), Path("again.toml"))
    assert back.scenario == sc and 'shape = "cylinder"' in scene_text(sc, f.name)
    # a box holds no shape: its fields, repr and asdict are a box's; a cylinder is told apart
    assert "shape" not in {x.name for x in dataclasses.fields(Box)} and "shape" not in dataclasses.asdict(book)
    assert "shape" not in repr(book) and dataclasses.asdict(mug)["shape"] == "cylinder"
    twin = Box(mug.name, mug.half, mug.x, mug.y, mass=mug.mass)
    assert twin != mug and repr(twin) != repr(mug)
    assert dataclasses.replace(mug, x=0.5).shape == "cylinder"
    with pytest.raises(SceneError, match="radius, radius, half height"):
        Cylinder("c", (0.02, 0.03, 0.05), 0.4, 0.3)
    for tasks, digest in SHIPPED_DIGESTS.items():
        assert task_digest(robot, tasks, (1, 2, 3)) == digest
    # a fixed cylinder keeps its radius where positions scale with the robot (a wall would stretch)
    placed = dataclasses.replace(sc, fixed=(post,))
    from lmjx.sim.scenarios import placed as place

    assert place(placed, 1.5).fixed[0] == dataclasses.replace(post, x=post.x * 1.5, y=post.y * 1.5)


BAD = [
    (_edit(BASE, "radius = 0.04\nheight = 0.11", "size = [0.08, 0.08, 0.11]"),
     "obstacles[1]: a cylinder takes radius and height, not size"),
    (_edit(BASE, 'name = "book"               # a box: size, as every object without a shape',
           'name = "book"\nradius = 0.03'), "obstacles[2]: 'radius' is a cylinder's: give a box size"),
    (_edit(BASE, "radius = 0.03               # [m]", "radius = -0.03"),
     "target.radius: give a number above 0 and at most 1, got -0.03"),
    (_edit(BASE, "height = 0.08               # [m] standing on the table", 'height = "8 cm"'),
     "target.height: give a number above 0 and at most 2, got '8 cm'"),
    (_edit(BASE, "height = 0.3\n", ""), "fixed[1]: 'height' is missing: give [m] the cylinder's height"),
    (_edit(BASE, 'shape = "cylinder"\nradius = 0.04', 'shape = "sphere"\nradius = 0.04'),
     "obstacles[1].shape: give \"box\" or \"cylinder\", got 'sphere'"),
    # geometry: circles (two cylinders 7.3 cm apart, radii 4 and 3 cm: closer than the 4 mm gap)
    (_edit(BASE, "position = [0.53, 0.35]", "position = [0.493, 0.36]"), "'target' and 'mug' overlap at their nominal"),
    (_edit(BASE, "position = [0.62, 0.56]", "position = [0.02, 0.0]"), "'lamp_post' at (0.02, 0) passes through"),
    (_edit(BASE, "position = [0.62, 0.56]", "position = [0.62, 1.5]"), "'lamp_post' at (0.62, 1.5) reaches off"),
    # a wide round slab under the whole goal region (centred at the target + 15 cm at 80 degrees)
    (_edit(BASE, "radius = 0.02\nheight = 0.3\nposition = [0.62, 0.56]",
           "radius = 0.1\nheight = 0.02\nposition = [0.446, 0.508]"),
     "is covered by the fixed obstacle 'lamp_post'"),
]  # fmt: skip


@pytest.mark.parametrize("text,message", BAD, ids=[f"bad{i}" for i in range(len(BAD))])
def test_a_bad_cylinder_is_one_line(text, message, tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SceneError, match=re.escape(message)) as e:
        lmjx.load_scene(path)
    assert "\n" not in str(e.value)


def test_circles_are_exact_where_squares_would_overlap(robot, tmp_path):
    """Two cylinders placed diagonally (their circumscribed squares overlap, their circles
    keep 4 mm apart) pass the checks; off the table a cylinder reaches its radius plus its
    jitter, not its square's half diagonal."""
    from lmjx.sim.footprint import rect_rect

    at = 0.0745 / math.sqrt(2)
    (tmp_path / "ok.toml").write_text(_edit(BASE, "position = [0.53, 0.35]", f"position = [{0.42 + at}, {0.36 + at}]"))
    task = lmjx.load_scene(tmp_path / "ok.toml")
    t, mug = task.scenario.movable[:2]
    assert math.hypot(mug.x - t.x, mug.y - t.y) - t.radius - mug.radius > 0.004
    squares = [rect_corners(np.array(b.half), np.array([b.x, b.y, 0.0]), 0.002) for b in (t, mug)]
    assert rect_rect(*squares)  # (boxes of these sizes would overlap)
    arm = robot.arm
    hi = float(arm.table_center[0] + arm.table_half[0])
    far = _edit(BASE, "angle = 80.0", "angle = 180.0")
    (tmp_path / "edge.toml").write_text(_edit(far, "position = [0.42, 0.36]", f"position = [{hi - 0.041}, 0.36]"))
    lmjx.load_scene(tmp_path / "edge.toml")  # its circle and its 1 cm jitter reach 1 mm short of the edge
    (tmp_path / "off.toml").write_text(_edit(far, "position = [0.42, 0.36]", f"position = [{hi - 0.039}, 0.36]"))
    with pytest.raises(SceneError, match=r"'target' at .* is off the table"):
        lmjx.load_scene(tmp_path / "off.toml")


def test_footprints_against_brute_force_points():
    """`rect_distance`, `circle_rect`, `circle_circle` and `footprints_overlap` against dense
    points on the shapes (the distance as the nearest of them, overlap as a shared point)."""
    rng = np.random.default_rng(5)
    u = np.linspace(-1.0, 1.0, 201)
    judged = 0
    for _ in range(60):
        half = rng.uniform(0.01, 0.06, 3)
        pose = np.array([*rng.uniform(-0.05, 0.05, 2), rng.uniform(-np.pi, np.pi)])
        c, s = math.cos(pose[2]), math.sin(pose[2])
        gx, gy = np.meshgrid(u * half[0], u * half[1])
        pts = np.stack([gx.ravel() * c - gy.ravel() * s + pose[0], gx.ravel() * s + gy.ravel() * c + pose[1]], 1)
        p = rng.uniform(-0.12, 0.12, 2)
        brute = np.hypot(*(pts - p).T).min()
        assert rect_distance(p, half, pose) == pytest.approx(brute, abs=half.max() / 100 + 1e-12)
        r, grow = rng.uniform(0.005, 0.05), rng.uniform(0.0, 0.003)
        big = rect_distance(p, half[:2] + grow, pose)
        if abs(big - (r + grow)) > BRUTE_TOL:
            judged += 1
            assert bool(circle_rect(p, r, half, pose, grow)) == (big <= r + grow)
            # the same through the objects, and against the points of the unchanged rectangle
            cyl, box = Cylinder("c", (r, r, 0.05), *p), Box("b", tuple(half), *pose[:2], yaw=pose[2])
            at = np.array([*p, 0.3])
            one, other = footprints_overlap(cyl, at, box, pose, grow), footprints_overlap(box, pose, cyl, at, grow)
            assert bool(one) == bool(other)
            if grow == 0.0 or abs(brute - r) > 2 * BRUTE_TOL:
                assert bool(footprints_overlap(cyl, at, box, pose, 0.0)) == (brute <= r)
        rb = rng.uniform(0.005, 0.05)
        d = math.hypot(*(p - pose[:2]))
        a = np.linspace(0, 2 * np.pi, 720)
        ring = pose[:2] + rb * np.stack([np.cos(a), np.sin(a)], 1)
        nearest = np.hypot(*(ring - p).T).min()  # the circle's points nearest the other circle's centre
        if abs(nearest - r) > BRUTE_TOL and d > rb:
            assert bool(circle_circle(p, r, pose[:2], rb, 0.0)) == (nearest <= r)
    assert judged > 40


def test_layouts_keep_cylinders_apart_by_their_circles():
    """`sample_layout` of a scene of cylinders and boxes: every draw keeps the footprints at
    least the 4 mm gap apart, measured on brute-force points of the circles and rectangles."""
    sc = read_scene(MUGS).scenario
    sc = dataclasses.replace(sc, jitter=0.03)
    for seed in range(5):
        poses = sample_layout(sc, seed).poses
        objs = list(zip(sc.movable, poses, strict=True)) + [(f, np.array([f.x, f.y, f.yaw])) for f in sc.fixed]
        pts = [_points(b, p) for b, p in objs]
        for i in range(len(objs)):
            for j in range(i + 1, len(objs)):
                gap = np.min(np.hypot(*(pts[i][:, None] - pts[j][None]).transpose(2, 0, 1)))
                assert gap >= 0.004 - 1e-3, (objs[i][0].name, objs[j][0].name, gap)


def _points(b: Box, pose: np.ndarray) -> np.ndarray:
    """Points on the outline of b's footprint at pose."""
    if b.shape == "cylinder":
        a = np.linspace(0, 2 * np.pi, 400, endpoint=False)
        return pose[:2] + b.half[0] * np.stack([np.cos(a), np.sin(a)], 1)
    c = rect_corners(np.array(b.half), pose, 0.0)
    t = np.linspace(0, 1, 100, endpoint=False)[:, None]
    return np.concatenate([c[k] + t * (c[(k + 1) % 4] - c[k]) for k in range(4)])


def test_the_mujoco_cylinder_against_c_mujoco(robot):
    """The scene's cylinder geoms: type, size, mass and friction as written; C MuJoCo's
    distance between two upright cylinders is their centres' distance less both radii; a
    cylinder set on the table rests there, upright."""
    from lmjx.sim.scene import build_scene, object_qpos, set_state

    sc = read_scene(MUGS).scenario
    scene = build_scene(robot, sc)
    m = scene.model
    for b in (*sc.movable, *sc.fixed):
        g = m.geom(f"{b.name}_geom" if b.movable else b.name)
        want = mujoco.mjtGeom.mjGEOM_CYLINDER if b.shape == "cylinder" else mujoco.mjtGeom.mjGEOM_BOX
        assert g.type[0] == want and g.friction[0] == b.friction
        size = [b.half[0], b.half[2]] if b.shape == "cylinder" else list(b.half)
        np.testing.assert_array_equal(g.size[: len(size)], size)
        if b.movable:
            assert m.body(b.name).mass[0] == pytest.approx(b.mass, rel=1e-12)
    d = mujoco.MjData(m)
    poses = np.array([[b.x, b.y, b.yaw] for b in sc.movable])
    set_state(scene, d, np.zeros(robot.nq), object_qpos(scene, poses))
    t, mug = sc.movable[:2]
    for dx in (0.08, 0.1, 0.2):
        qpos = object_qpos(scene, np.array([[t.x, t.y, 0.3], [t.x + dx, t.y, 1.1], poses[2]]))
        set_state(scene, d, np.zeros(robot.nq), qpos)
        dist = mujoco.mj_geomDistance(m, d, m.geom("target_geom").id, m.geom("mug_geom").id, 1.0, None)
        assert dist == pytest.approx(dx - t.radius - mug.radius, abs=1e-6)
    set_state(scene, d, np.zeros(robot.nq), object_qpos(scene, poses))
    for _ in range(200):
        mujoco.mj_step(m, d)
    z = d.qpos[scene.obj_qpos[0] + 2]
    assert z == pytest.approx(t.half[2], abs=2e-3) and abs(d.qpos[scene.obj_qpos[0] + 4]) < 1e-3


def test_the_planners_clearance_to_a_cylinder_against_c_mujoco(robot):
    """The planner's clearance to a cylinder (`sceneboxes`: the clearance program that takes
    cylinders, `kernels.collision.cylinder_sdf`) against C MuJoCo's distance between the
    arm's capsules and the cylinder geom, at random configurations near it; its lower bound
    never above it; the same post as a box: the boxes' program, farther in at its corners."""
    from lmjx.sim.scene import build_scene
    from lmjx.sim.sceneboxes import SceneClearance, scene_boxes

    post = Cylinder("post", (0.08, 0.08, 0.3), 0.4, 0.1, yaw=0.3, movable=False)
    sc = Scenario(0, "post", "", Cylinder("target", (0.03, 0.03, 0.04), 0.6, -0.4), (), fixed=(post,))
    scene = build_scene(robot, sc)
    m, d = scene.model, mujoco.MjData(scene.model)
    arm_bodies = {robot.mj.body(b).name for b in range(1, robot.mj.nbody)}
    caps = [g for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE
            and m.body(int(m.geom_bodyid[g])).name in arm_bodies]  # fmt: skip
    assert len(caps) == len(robot.arm.cap_r)  # (the kernel's capsules are the model's)
    qs = random_configs(robot, 300, 11)
    ref = np.empty(len(qs))
    g_post = m.geom("post").id
    for i, q in enumerate(qs):
        d.qpos[scene.robot_qpos] = q
        mujoco.mj_kinematics(m, d)
        ref[i] = min(mujoco.mj_geomDistance(m, d, g, g_post, 2.0, None) for g in caps)
    near = ref < 0.1
    assert (ref[near] > 0).sum() >= 15 and (ref[near] < 0).sum() >= 5
    checks = SceneClearance(robot, batched=True)
    boxes = scene_boxes(sc, np.array([[0.6, -0.4, 0.04, 1.0, 0.0, 0.0, 0.0]]))
    checks.place(boxes)
    got = checks.box_clearance(qs[near])[:, 1]
    err = np.abs(got - ref[near])
    assert (err <= np.where(ref[near] > 0, KERNEL_TOL, DEPTH_TOL)).all(), err.max()
    assert (checks.lower_bounds(qs[near])[:, 1] <= got + 1e-6).all()
    # the same scene with the post a box of its size: the boxes' program, and the box's clearance
    as_box = dataclasses.replace(boxes, cylinders=np.zeros(2, bool))
    checks.place(as_box)
    square = checks.box_clearance(qs[near])[:, 1]
    assert list(checks._box_kernels[4].programs) == [True, False] and not checks._box_kernels[4].cylinders
    assert (square <= got + KERNEL_TOL).all() and (square < got - 1e-3).any()


def test_the_viewers_cylinder_is_the_solid():
    """`shapes.cylinder`: its corners on the circle, flat caps at +-half height, every face
    facing out, and its volume the inscribed prism's (divergence theorem)."""
    from lmjx.view.shapes import cylinder

    r, h, n = 0.04, 0.055, 16
    mesh = cylinder(r, h, n)
    v = mesh.vertices.astype(np.float64)
    side = v[: 2 * n]
    np.testing.assert_allclose(np.hypot(side[:, 0], side[:, 1]), r, rtol=1e-6)
    assert set(np.round(v[:, 2], 6)) == {round(-h, 6), round(h, 6)}
    tri = v[mesh.faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert (np.einsum("ij,ij->i", normal, tri.mean(axis=1)) > 0).all()
    volume = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
    assert volume == pytest.approx(n / 2 * math.sin(2 * math.pi / n) * r * r * 2 * h, rel=1e-5)


def test_the_path_field_walls_off_a_fixed_cylinder_by_its_circle(robot):
    """`GoalField`: a fixed cylinder between the target and the goal is a wall of its radius
    grown by the target's (a disc: a point just outside it is free, one inside is walled)."""
    from lmjx.planner.scoring import table_bounds
    from lmjx.sim.goalfield import GoalField

    sc = read_scene(MUGS).scenario
    post = Cylinder("post", (0.05, 0.05, 0.1), 0.45, 0.3, movable=False)
    sc = dataclasses.replace(sc, fixed=(post,), goal_center=(0.45, 0.45))
    f = GoalField(sc, *table_bounds(robot))
    reach = post.radius + sc.target.radius
    behind = np.array([0.45, 0.3 - reach - 0.02])
    assert not f.euclidean and f(behind) > np.hypot(*(behind - sc.goal_center)) + 0.01
    corner = np.array([0.45 + 0.066, 0.3 + 0.066])  # 1.4 cm inside the grown square, 1.3 cm outside the disc
    assert math.hypot(0.066, 0.066) > reach > 0.066
    assert f(corner) < np.hypot(*(corner - sc.goal_center)) * 1.1  # free (the grid's paths: 8 % longer at most)


def test_a_cylinder_scene_is_checked_planned_evaluated_viewed_and_exported(plan_map, robot, tmp_path):
    """examples/my_mugs.toml (a cylinder target, a cylinder mug, a fixed cylinder post):
    scenarios --check --map; plan with each ASM (one action, Greedy of 4 candidates, CPU);
    evaluate; view as a scene and as the greedy trial (HTML); the greedy trial's action as a
    ROS JointTrajectory (lmjx.transit of the recorded edge from the trial's first
    observation, lmjx.trajectory)."""
    from lmjx.view.recording import decode_recording, latest_nodes

    check = cli("scenarios", "--check", MUGS, "--map", plan_map).ok().stdout
    assert "ok (my mugs: the target, 2 movable objects, 1 fixed obstacle (3 of them cylinders)," in check
    assert "goal reached on" in check
    plans = {}
    for asm in ("random", "lazy", "greedy"):
        r = cli("plan", "--map", plan_map, "--scene", MUGS, "--asm", asm, "--max-actions", "1", "--candidates", "4",
                "--sim", "cpu", "--seed", "0", "--json").ok()  # fmt: skip
        plans[asm] = json.loads(r.stdout)
        rec = plans[asm]
        assert rec["task"] == "my mugs" and rec["actions"] == 1 and rec["steps"][0]["edge"] >= 0, (asm, rec["end"])
        assert rec["scene"]["kind"] == "scene" and 'shape = "cylinder"' in rec["scene"]["text"]
    out = tmp_path / "ev"
    cli("evaluate", "--failures", "case2", "--scenes", MUGS, "--asms", "random", "--trials", "1", "--max-actions", "1",
        "--maps", plan_map.parent, "--out", out).ok()  # fmt: skip
    trials = json.loads((out / "results.json").read_text())["trials"]
    assert len(trials) == 1 and trials[0]["scene"]["kind"] == "scene" and trials[0]["actions"] == 1

    def nodes(path: Path) -> dict:
        data = re.search(r'window.__VISER_EMBED_DATA__="([A-Za-z0-9+/=]+)"', path.read_text())
        assert data is not None
        import base64

        return latest_nodes(decode_recording(base64.b64decode(data.group(1)))[1])

    cli("view", MUGS, "--map", plan_map, "--html", tmp_path / "scene.html").ok()
    drawn = nodes(tmp_path / "scene.html")
    tin = drawn["/scene/bodies/target/target_geom"].array("props", "vertices").reshape(-1, 3)
    assert len(tin) == 2 * 16 + 2 and np.allclose(sorted(set(np.round(tin[:, 2], 6))), [-0.04, 0.04])
    np.testing.assert_allclose(drawn["/scene/static/lamp_post"].fields["position"][:2], (0.62, 0.56), atol=1e-9)
    (tmp_path / "plan.json").write_text(json.dumps(plans["greedy"]))
    cli("view", tmp_path / "plan.json", "--map", plan_map, "--html", tmp_path / "trial.html").ok()
    assert "/trial/bodies/mug/mug_geom" in nodes(tmp_path / "trial.html")

    step = plans["greedy"]["steps"][0]
    m = lmjx.load_map(plan_map)
    task = lmjx.load_scene(MUGS, map_file=m)
    seed = plans["greedy"]["seed"]
    world = lmjx.SimulatedRealWorld(m.robot, seed)
    park = lmjx.park_pose(m)
    obs = world.reset(task.layout(seed), park)
    edge = m.edge(step["edge"], math.radians(step.get("turn_deg", 0)))  # (a record leaves out a turn of 0)
    t = lmjx.transit(m.robot, task, park, edge, objects=obs.objects)
    assert t and t.action.edge == step["edge"] and t.route == step["transit_route"], t
    traj = lmjx.trajectory(t, joint_names=list(m.robot.joint_names))
    traj.write(tmp_path / "action.json")
    msg = json.loads((tmp_path / "action.json").read_text())
    assert msg["joint_names"] == list(m.robot.joint_names) and len(msg["points"]) == len(traj.t)
    np.testing.assert_allclose(msg["points"][0]["positions"], park, atol=1e-12)
    assert not any(msg["points"][0]["velocities"]) and not any(msg["points"][-1]["velocities"])
    end = msg["points"][-1]["time_from_start"]
    assert end["sec"] + end["nanosec"] * 1e-9 == pytest.approx(traj.t[-1], abs=1e-9)
