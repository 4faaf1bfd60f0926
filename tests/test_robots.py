"""Robots: the contract of docs/ROBOTS.md, `lmjx robot check`, `lmjx robots`, the UR5e, the
robot recorded in map and atlas files, scenarios scaled to an arm's size."""

from __future__ import annotations

import json
import re

import h5py
import mujoco
import numpy as np
import pytest
from conftest import cli

from lmjx.errors import ConfigError, FailureSpecError, MapFileError
from lmjx.model.failure import parse_failure
from lmjx.model.robot import ROBOTS, RobotError, check_robot, load_robot, resolve_robot
from lmjx.reach.atlas import AtlasConfig, entries, expected_maps
from lmjx.sim.scenarios import PAPER_BUDGET, PAPER_TASKS, in_goal, sample_layout, scenario

UR5E = ROBOTS["ur5e"]


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_shipped_robots_meet_the_contract(name):
    assert check_robot(ROBOTS[name]) == []
    r = cli("robot", "check", str(ROBOTS[name]))
    assert r.returncode == 0 and "an lmjx robot" in r.stdout, r.stderr


# A broken copy of the UR5e for each part of the contract: (edit, what the one error line names)
BROKEN = {
    "missing tcp": (lambda t: re.sub(r'\s*<site name="tcp"[^>]*/>', "", t), "no site 'tcp'"),
    "joint without limits": (
        lambda t: t.replace('<joint name="wrist_1" act', '<joint name="wrist_1" limited="false" act'),
        "joint 'wrist_1' has no position limits",
    ),
    "link without collision geometry": (
        lambda t: re.sub(r'\s*<geom name="wrist_2_c0"[^>]*/>', "", t),
        "body 'wrist_2_link' has no collision geometry",
    ),
    "no interaction points": (lambda t: re.sub(r'\s*<site name="ip_[^>]*/>', "", t), "no interaction-point sites"),
    "joint off its body's origin": (
        lambda t: t.replace('<joint name="elbow" ', '<joint name="elbow" pos="0 0 0.01" '),
        "joint 'elbow' is off its body's origin",
    ),
    "no velocity limits": (lambda t: re.sub(r'\s*<numeric name="lmjx_qd_max"[^>]*/>', "", t), "no velocity limits"),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_robot_check_names_the_problem(case, tmp_path):
    edit, message = BROKEN[case]
    text = UR5E.read_text()
    broken = edit(text)
    assert broken != text
    path = tmp_path / "arm.xml"
    path.write_text(broken)
    problems = check_robot(path)
    assert len(problems) == 1 and message in problems[0], problems
    r = cli("robot", "check", str(path))
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and message in lines[0] and str(path) in lines[0], r.stderr
    with pytest.raises(RobotError, match=re.escape(message)):
        load_robot(str(path))
    # every command refuses it the same way, in one line
    r = cli("reach", "--robot", str(path), "--failure", "none")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and message in r.stderr, r.stderr


def test_robot_check_lists_every_problem_and_reads_no_junk(tmp_path):
    text = BROKEN["missing tcp"][0](BROKEN["no interaction points"][0](UR5E.read_text()))
    (tmp_path / "two.xml").write_text(text)
    r = cli("robot", "check", str(tmp_path / "two.xml"))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 2, r.stderr
    (tmp_path / "junk.xml").write_text("<mujoco><worldbody><body>")
    r = cli("robot", "check", str(tmp_path / "junk.xml"))
    assert r.returncode == 2 and "MuJoCo cannot load it" in r.stderr and "Traceback" not in r.stderr
    for args, message in (
        (("robot", "check", str(tmp_path / "missing.xml")), "no robot description"),
        (("reach", "--robot", "kuka", "--failure", "none"), "unknown robot 'kuka'"),
    ):
        r = cli(*args)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and message in r.stderr, r.stderr


def test_robots_command_lists_the_shipped_arms():
    r = cli("robots", "--json")
    assert r.returncode == 0, r.stderr
    rows = {x["name"]: x for x in json.loads(r.stdout)["robots"]}
    assert set(rows) == {"panda", "ur5e"}
    assert rows["panda"]["joints"] == 7 and rows["ur5e"]["joints"] == 6
    assert set(rows["panda"]["presets"]) == {"case1", "case2"} and set(rows["ur5e"]["presets"]) == {"case1", "case2"}


def test_presets_live_with_each_robot():
    panda, ur = load_robot("panda"), load_robot("ur5e")
    # the Panda's presets are the ones Table I was computed with
    assert parse_failure("case1", panda).locked == ((3, 2.8773), (5, 0.0), (7, np.pi / 4))
    assert parse_failure("case2", panda).locked == ((6, 0.935), (7, -0.7193))
    for name in ("case1", "case2"):
        f = parse_failure(name, ur)
        assert f.nq == 6 and f.locked and all(1 <= j <= 6 for j in f.locked_joints)
        assert f.locked != parse_failure(name, panda).locked
    with pytest.raises(FailureSpecError, match=r"J7 does not exist; joints are J1\.\.J6"):
        parse_failure("J7=0.1", ur)
    assert resolve_robot(None) == ("panda", ROBOTS["panda"])
    assert resolve_robot(str(UR5E))[0] == "ur5e"  # a shipped file by its path is that robot


def test_ur5e_model_is_urs():
    """q = 0 is UR's zero configuration (the arm stretched along -x at the shoulder's height,
    the tool pointing along -y, UR's signs); limits and masses as published."""
    ur = load_robot("ur5e")
    m, d = ur.mj, mujoco.MjData(ur.mj)
    mujoco.mj_kinematics(m, d)
    np.testing.assert_allclose(d.site_xpos[ur.flange_site], [-0.8172, -0.2329, 0.0628], atol=1e-9)
    np.testing.assert_allclose(ur.tau_max, [150, 150, 150, 28, 28, 28])
    np.testing.assert_allclose(ur.qd_max, np.pi, rtol=1e-5)
    np.testing.assert_allclose(ur.upper, [2 * np.pi, 2 * np.pi, np.pi, 2 * np.pi, 2 * np.pi, 2 * np.pi], rtol=1e-5)
    masses = [m.body(n).mass[0] for n in ("shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link")]
    np.testing.assert_allclose(masses, [3.761, 8.058, 2.846, 1.37])
    # the tool: the gripper stand-in, grasp point 0.145 m beyond the flange along its axis
    flange_z = d.site_xmat[ur.flange_site].reshape(3, 3)[:, 2]
    np.testing.assert_allclose(d.site_xpos[ur.tcp_site] - d.site_xpos[ur.flange_site], 0.145 * flange_z, atol=1e-12)
    assert ur.tool_body_name == "gripper" and ur.default_ips == ("hand", "wrist", "forearm")


def test_ur5e_ready_pose_and_scene_hold_still():
    """The UR5e parks collision-free, and the planner's scene (6 joint servos) holds it there
    with every object of scenario 3 at rest."""
    from lmjx.planner.clearance import park_pose
    from lmjx.sim.controls import controls
    from lmjx.sim.scenarios import sample_layout
    from lmjx.sim.scene import build_scene, object_qpos, read_objects, set_state
    from lmjx.types import Action

    ur = load_robot("ur5e")
    q = park_pose(ur, parse_failure("case2", ur))
    d = mujoco.MjData(ur.mj)
    d.qpos[:] = q
    mujoco.mj_forward(ur.mj, d)
    assert d.ncon == 0
    sc = scenario(3, ur.profile.task_scale, "hard")
    s = build_scene(ur, sc)
    sd = mujoco.MjData(s.model)
    start = object_qpos(s, sample_layout(sc, 0).poses)
    set_state(s, sd, q, start)
    hold = Action(edge=0, q=np.repeat(q[None], 5, 0), qd=np.zeros((5, 6)), transit_steps=0, via_park=False)
    u = controls(hold, 0.005, 0.5)
    assert u.shape[1] == 12
    for ui in u:
        sd.ctrl[:] = ui
        mujoco.mj_step(s.model, sd)
    assert np.abs(sd.qpos[s.robot_qpos] - q).max() < 1e-3
    assert np.abs(read_objects(s, sd)[:, :3] - start[:, :3]).max() < 1e-3


def test_scenarios_scale_about_the_base():
    assert scenario(2, 1.0, "hard") == scenario(2, tasks="hard")
    a, b = scenario(2, tasks="hard"), scenario(2, 1.2, "hard")
    assert b.target.x == pytest.approx(1.2 * a.target.x) and b.goal_center[1] == pytest.approx(1.2 * a.goal_center[1])
    assert b.target.half == a.target.half  # objects keep their size
    for fa, fb in zip(a.fixed, b.fixed, strict=True):  # the tunnel's walls grow along their length only
        assert fb.half[0] == pytest.approx(1.2 * fa.half[0]) and fb.half[1:] == fa.half[1:]
    with pytest.raises(ConfigError):
        scenario(1, 0.0)
    with pytest.raises(ConfigError, match="task set"):
        scenario(1, tasks="easy")


def test_paper_tasks_keep_the_hard_layouts():
    """The paper set keeps the hard layouts (the tunnel's task reversed), puts the goal at the
    calibrated distance and direction; no layout starts in its goal."""
    for n, task in PAPER_TASKS.items():
        hard, paper = scenario(n, tasks="hard"), scenario(n, tasks="paper")
        assert (paper.tasks, paper.budget, hard.budget) == ("paper", PAPER_BUDGET, 30)
        assert paper.obstacles == hard.obstacles and paper.fixed == hard.fixed
        start, goal = np.array([paper.target.x, paper.target.y]), np.array(paper.goal_center)
        a = np.radians(task.angle)
        assert goal - start == pytest.approx(task.distance * np.array([np.cos(a), np.sin(a)]))
        assert paper.goal_half == (task.half, task.half)
        for seed in range(20):
            assert not in_goal(paper, sample_layout(paper, seed).poses[0, :2])
        if hard.fixed:  # reversed: from the hard task's goal, through the tunnel, wholly past the wall
            assert (paper.target.x, paper.target.y) == hard.goal_center
            assert goal[1] - task.half >= max(f.y + f.half[1] for f in hard.fixed)
        else:
            assert paper.target == hard.target


def test_atlas_of_the_ur5e_has_675_maps():
    ur = load_robot("ur5e")
    joints, _ = entries(ur, AtlasConfig())
    assert len(joints) == expected_maps((2, 3), 3, ur.nq) == 15 * 9 + 20 * 27 == 675
    assert joints.max() == 6


def test_map_files_name_their_robot(table1_ur5e, tmp_path):
    """A map records its robot; load_map takes the robot it names and refuses another."""
    from lmjx.mapfile.read import load_map
    from lmjx.mapfile.write import write_reach_map

    ur = load_robot("ur5e")
    res = table1_ur5e["case2"]
    path = tmp_path / "ur.h5"
    write_reach_map(path, res, ur)
    with h5py.File(path) as f:
        assert f.attrs["robot"] == "ur5e"
    m = load_map(path)  # no robot given: the file's
    assert m.robot is ur and m.failure.locked == parse_failure("case2", ur).locked
    with pytest.raises(MapFileError, match="built for the robot 'ur5e', not 'panda'"):
        load_map(path, load_robot("panda"))
    r = cli("info", str(path), "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["robot"] == "ur5e", r.stderr
    r = cli("info", str(path), "--robot", "panda")
    assert r.returncode == 2 and "not 'panda'" in r.stderr
    with h5py.File(path, "a") as f:  # a map of a user's robot needs its file
        f.attrs["robot"] = "my_arm"
    with pytest.raises(MapFileError, match="pass --robot PATH"):
        load_map(path)


def test_user_robot_by_path_scales_its_scenarios(tmp_path):
    """Any MJCF meeting the contract is a robot: a UR5e 1.5 times as large, by its path, gets
    its scenarios and task plane scaled with it."""
    text = UR5E.read_text()
    edits = (("0.1625", "0.24375"), ("-0.425 ", "-0.6375 "), ("-0.3922 ", "-0.5883 "), ('"lmjx_ur5e"', '"big"'))
    for a, b in edits:
        text = text.replace(a, b)
    path = tmp_path / "big.xml"
    path.write_text(text)
    big = load_robot(str(path))
    assert big.key == str(path) and big.maps_dir == "maps/big"
    assert 1.2 < big.profile.task_scale < 1.5
    from lmjx.reach.reachability import reach_config

    cfg = reach_config(big)
    assert cfg.x_range[1] == pytest.approx(1.1 * big.profile.task_scale)
