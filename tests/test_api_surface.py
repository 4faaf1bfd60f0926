"""Mistakes at the public API's surface: wrong types and values given to `MapFile.edges_over`,
`MapFile.edge`, `transit`, `simulate`, `trajectory`, `park_pose` and `Layout` are each an
`LmjxError` with a one-line message, never a raw AttributeError, TypeError or KeyError;
quaternions in either order (`order="wxyz"`, MuJoCo's; `"xyzw"`, ROS's) give the same
results; a trial's poses of one's own are a public `Layout` an executor resets to.  On the
planner tests' case-2 map (`plan_map`) and the paper's scenario 1."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import lmjx


@pytest.fixture(scope="module")
def m(plan_map: Path):
    with lmjx.load_map(plan_map) as opened:
        yield opened


@pytest.fixture(scope="module")
def setting(m):
    """Scenario 1, its first layout, the park pose and a transit to an edge over the target."""
    task = lmjx.load_scene(lmjx.shipped_scene(1, "paper"), map_file=m)
    layout = task.layout(0)
    x, y = layout.poses[0, :2]
    q_park = lmjx.park_pose(m)
    for i in m.edges_over((x - 0.035, y - 0.035, x + 0.035, y + 0.035))[:80]:
        t = lmjx.transit(m.robot, task, q_park, m.edge(int(i)), objects=layout.poses)
        if t:
            return task, layout, q_park, t
    pytest.fail("no edge over scenario 1's target has a transit")


def _one_line(call, match: str) -> None:
    with pytest.raises(lmjx.LmjxError, match=match) as err:
        call()
    assert "\n" not in str(err.value), str(err.value)


def test_edges_over_and_edge_refuse_in_one_line(m):
    for region in (None, 3.0, "0,0,1,1", (0, 0, 1), ("a", 0, 1, 1), (0, 0, float("nan"), 1), [(0, 1), (0, 1)]):
        _one_line(lambda r=region: m.edges_over(r), "a region is")
        _one_line(lambda r=region: m.edges_over(r, turned=True), "a region is")
    _one_line(lambda: m.edges_over((0.3, 0.3, 0.4, 0.4), turned="yes"), "turned is True or False")
    for index in (None, 1.5, "3", True, -1, m.edges.n_edges):
        _one_line(lambda i=index: m.edge(i), "does not exist")
    ids, turns = m.edges_over((0.3, 0.3, 0.4, 0.4), turned=True)
    assert ids.shape == turns.shape and (turns[np.flatnonzero(turns)] != 0).all()


def test_transit_refuses_in_one_line(m, setting):
    task, _, q_park, _ = setting
    e = m.edge(0)
    for args, match in (
        (("ur6", task, q_park, e), "unknown robot"),
        ((3, task, q_park, e), "a robot is a name"),
        ((m.robot, "scenario 1", q_park, e), "the scene is a Task"),
        ((m.robot, task, q_park, 0), "give an edge from MapFile.edge, got int"),
        ((m.robot, task, q_park[:3], e), "give the 7 joint angles"),
        ((m.robot, task, "park", e), "q_from: give the 7 joint angles"),
        ((m.robot, task, np.full(7, np.nan), e), "give the 7 joint angles"),
    ):
        _one_line(lambda a=args: lmjx.transit(*a), match)
    for kwargs, match in (
        ({"objects": np.zeros((2, 7))}, r"give \(4, 7\) poses"),
        ({"objects": "here"}, "objects: give"),
        ({"objects": np.zeros((4, 7))}, "the quaternions' norms are"),
        ({"objects": np.full((4, 3), np.inf)}, "not finite"),
        ({"after": "the last"}, "after is the Action executed last"),
        ({"acting": "yes"}, "acting is True or False"),
        ({"order": "zyxw"}, "a quaternion's order is 'wxyz'"),
    ):
        _one_line(lambda k=kwargs: lmjx.transit(m.robot, task, q_park, e, **k), match)
    ur = lmjx.load_scene(lmjx.shipped_scene(1, "paper"), "ur5e")
    _one_line(lambda: lmjx.transit("ur5e", ur, np.zeros(6), e), "edge is of a map of the robot panda, not ur5e")


def test_simulate_refuses_in_one_line(m, setting):
    task, layout, q_park, t = setting
    world = lmjx.SimulatedRealWorld(m.robot, seed=0)
    obs = world.reset(layout, q_park)
    for args, kwargs, match in (
        (("scenario", obs, [t.action]), {}, "the scene is a Task"),
        ((task, "obs", [t.action]), {}, "state is an Observation"),
        ((task, obs, t.action), {}, "actions is a list of Actions, got Action"),
        ((task, obs, [t]), {}, "got a Transit"),
        ((task, obs, [t.action]), {"sim": "fast"}, "unknown simulator"),
        ((task, obs, [t.action]), {"sim": 1}, "sim is 'cpu'"),
        ((task, obs, [t.action]), {"servo": "stiff"}, "servo is 'robot' or 'playback'"),
        ((task, obs, [t.action]), {"order": "xyz"}, "a quaternion's order"),
    ):
        _one_line(lambda a=args, k=kwargs: lmjx.simulate(*a, **k), match)
    bad = lmjx.Observation(np.zeros(3), obs.objects, 0.0)
    _one_line(lambda: lmjx.simulate(task, bad, [t.action]), "state.robot_q: give the 7 joint angles")


def test_trajectory_and_park_pose_refuse_in_one_line(m, setting):
    _, _, q_park, t = setting
    for args, kwargs, match in (
        ((7,), {}, "give an Edge .*, a Transit .* or an Action with q_from, got int"),
        ((t.action,), {}, r"an Action starts where the arm stands: give q_from=\.\.\."),
        ((t.action,), {"q_from": q_park}, "an Action does not name its joints"),
        ((t.action,), {"q_from": q_park[:4], "robot": m.robot}, "q_from: give the 7 joint angles"),
        ((t.action,), {"q_from": q_park + 1.0, "robot": m.robot}, "rad from the action's first joint target"),
        ((t.action,), {"q_from": q_park, "joint_names": ["a", "b"]}, "give the action's 7 joint names"),
        ((t,), {"dt": 0}, "dt must be a number of seconds above 0"),
        ((t,), {"dt": "0.01"}, "dt must be a number"),
        ((m.edge(0),), {"q_from": q_park}, "q_from is for an Action"),
        ((lmjx.Transit(3, None, "", "no transit: every way"),), {}, r"has no action \(no transit\)"),
    ):
        _one_line(lambda a=args, k=kwargs: lmjx.trajectory(*a, **k), match)
    _one_line(lambda: lmjx.trajectory(t).write(42), "a trajectory's file is a path")
    _one_line(lambda: lmjx.park_pose("maps/case2.h5"), "park_pose: give a map")


def test_quaternions_in_either_order(m, setting):
    """transit and simulate take (x, y, z, w) poses with order="xyzw" and give the same
    actions and ends, simulate's in that order."""
    task, layout, q_park, t = setting
    world = lmjx.SimulatedRealWorld(m.robot, seed=0)
    obs = world.reset(layout, q_park)
    xyzw = obs.objects[:, [0, 1, 2, 4, 5, 6, 3]]
    e = m.edge(t.edge)
    a = lmjx.transit(m.robot, task, q_park, e, objects=obs.objects)
    b = lmjx.transit(m.robot, task, q_park, e, objects=xyzw, order="xyzw")
    assert bool(a) == bool(b) and (not a or np.array_equal(a.action.q, b.action.q))
    ends = lmjx.simulate(task, obs, [t.action])
    flipped = lmjx.Observation(obs.robot_q, xyzw, obs.time)
    ends_xyzw = lmjx.simulate(task, flipped, [t.action], order="xyzw")
    assert np.array_equal(ends_xyzw, ends[..., [0, 1, 2, 4, 5, 6, 3]])
    assert np.allclose(np.linalg.norm(ends[..., 3:], axis=-1), 1.0)


def test_a_layout_of_ones_own_is_public(m, setting):
    task, layout, q_park, _ = setting
    mine = lmjx.Layout(task.scenario, 7, layout.poses + np.array([0.01, 0.0, 0.0]))
    obs = lmjx.SimulatedRealWorld(m.robot, seed=0).reset(mine, q_park)
    assert np.abs(obs.objects[:, :2] - mine.poses[:, :2]).max() < 0.01  # (observed with 2 mm noise)
    for args, match in (
        ((task, 0, layout.poses), "scenario is a task's"),
        ((task.scenario, 0, layout.poses[:2]), r"poses are \(4, 3\) finite x, y, yaw of target"),
        ((task.scenario, 0, "here"), r"poses are \(4, 3\)"),
        ((task.scenario, "0", layout.poses), "seed is a whole number"),
    ):
        _one_line(lambda a=args: lmjx.Layout(*a), match)
    world = lmjx.SimulatedRealWorld(m.robot, seed=0)
    for args, match in (
        ((task, q_park), "layout: give an lmjx.Layout"),
        ((layout.poses, q_park), "layout: give an lmjx.Layout"),
        ((layout, q_park[:3]), f"robot_q: give the arm's {m.robot.nq} joint angles"),
        ((layout, "park"), "robot_q: give the arm's"),
        ((layout, {"q": 1}), "robot_q: give the arm's"),
        ((layout, np.full(m.robot.nq, np.nan)), "robot_q: give the arm's"),
    ):
        _one_line(lambda a=args: world.reset(*a), match)
