"""The public API's turned edges and exported trajectories against independent references:
`MapFile.edges_over(region, turned=True)` is the planner's offer (`edges_over_target` then
`turned_over_target`); a turned `Edge` is C MuJoCo's forward kinematics of its turned joint
states; `lmjx.transit` of a turned edge executes those states; `lmjx.trajectory` of a whole
action runs from rest to rest through the action's joint targets, its velocities the finite
differences of its positions and its accelerations those of its velocities, on the planner's
time law; its files read back (JSON as a JointTrajectory, CSV) to the same numbers.  On the
planner tests' case-2 map (`plan_map`) and the paper's scenario 1."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import mujoco
import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

import lmjx
from lmjx.mapfile.trajectory import NS
from lmjx.planner.edge_planner import edges_over_target
from lmjx.planner.timelaw import RAMP, _law, ramped
from lmjx.planner.turned import turned_over_target
from lmjx.toolkit import time_law
from lmjx.types import CONTROL_DT

TARGETS = ((0.403, 0.419), (0.471, 0.183), (0.553, 0.297))  # (off the cells' edges: no float tie)
FK_TOLERANCE = 1e-5  # [m] the map's points are float32
TURN_TOLERANCE = 2e-7  # [rad] a turned angle is float32 (the planner's arithmetic)
KNOT_TOLERANCE = 1e-9  # [rad] the exported path passes through every planned joint target
FINE_DT = 0.0005  # [s] the period the derivatives are checked at
VELOCITY_TOLERANCE = 1e-3  # [rad/s] central differences of positions at FINE_DT (O(dt^2) off)
INTEGRAL_TOLERANCE = 1e-4  # [rad/s] [rad] trapezoidal integrals of accelerations / velocities at FINE_DT
ACCELERATION_SHARE = 0.03  # central differences of velocities within this share of the peak acceleration


@pytest.fixture(scope="module")
def m(plan_map: Path):
    with lmjx.load_map(plan_map) as opened:
        yield opened


@pytest.fixture(scope="module")
def scene(m):
    task = lmjx.load_scene(lmjx.shipped_scene(1, "paper"), map_file=m)
    return task, task.layout(0)


@pytest.fixture(scope="module")
def turned_transit(m, scene):
    """A transit from the park pose to a turned copy of an edge over scenario 1's target."""
    task, layout = scene
    x, y = layout.poses[0, :2]
    h = float(task.scenario.target.half[0]) + 0.01
    ids, turns = m.edges_over((x - h, y - h, x + h, y + h), turned=True)
    q_park = lmjx.park_pose(m)
    for k in np.random.default_rng(1).permutation(np.flatnonzero(turns))[:400]:
        t = lmjx.transit(m.robot, task, q_park, m.edge(int(ids[k]), turn=float(turns[k])), objects=layout.poses)
        if t:
            return t
    pytest.fail("no turned copy over scenario 1's target has a transit")


def test_the_turned_offer_is_the_planners(m):
    """edges_over(turned=True) over a target's square grown by the planner's margin: the
    planner's own edges (turn 0) then its turned copies, in the same order, to the bit."""
    for x, y in TARGETS:
        r = 0.035
        ids, turns = m.edges_over((x - r, y - r, x + r, y + r), turned=True)
        own = edges_over_target(m.edges, m.reach, np.array([x, y]), 0.025, 0.01)
        copies, delta = turned_over_target(m.edges, m.reach, m.robot, m.failure, np.array([x, y]), 0.025, 0.01)
        assert len(copies) > len(own) > 0
        assert np.array_equal(ids, np.concatenate([own, copies])) and ids.dtype == np.int64
        assert np.array_equal(turns, np.concatenate([np.zeros(len(own)), delta]))
        assert np.array_equal(m.edges_over((x - r, y - r, x + r, y + r)), own)


def test_a_turned_edge_is_c_mujocos_kinematics_of_its_turned_states(m):
    """A turned edge's states: the base joint turned (float32, as the planner executes them),
    every other joint and every velocity the stored edge's; C MuJoCo's mj_kinematics of each
    state puts the interaction point on the edge's turned path."""
    model = mujoco.MjModel.from_xml_path(str(m.robot.path))
    data = mujoco.MjData(model)
    adr = [model.joint(n).qposadr[0] for n in m.robot.joint_names]
    ids, turns = m.edges_over((0.37, 0.385, 0.44, 0.455), turned=True)
    pick = np.random.default_rng(0).permutation(np.flatnonzero(turns))[:6]
    for k in pick:
        i, turn = int(ids[k]), float(turns[k])
        e, stored = m.edge(i, turn=turn), m.edge(i)
        assert e.turn == turn and f"turned {turn:+.4f} rad" in repr(e)
        assert np.abs(e.q[:, 0] - (stored.q[:, 0] + turn)).max() < TURN_TOLERANCE
        assert np.array_equal(e.q[:, 1:], stored.q[:, 1:]) and np.array_equal(e.qd, stored.qd)
        site = model.site("ip_" + e.point).id
        for row, p in zip(e.q, e.p, strict=True):
            data.qpos[adr] = row
            mujoco.mj_kinematics(model, data)
            assert np.abs(data.site_xpos[site] - p).max() < FK_TOLERANCE
    assert np.array_equal(m.edge(int(ids[0]), turn=0.0).q, m.edge(int(ids[0])).q)


def test_a_turn_past_the_joints_limits_is_one_line(m):
    e = m.edge(0)
    low, high = m.robot.lower[0] - e.q[:, 0].min(), m.robot.upper[0] - e.q[:, 0].max()
    m.edge(0, turn=float(high) - 1e-9)
    for turn in (float(high) + 1e-3, float(low) - 1e-3, 7.0):
        with pytest.raises(lmjx.LmjxError, match=r"past its limits .*; this edge turns by") as err:
            m.edge(0, turn=turn)
        assert "\n" not in str(err.value)
    for turn in ("0.1", float("nan"), True, [0.1]):
        with pytest.raises(lmjx.LmjxError, match="a turn is a finite number of radians"):
            m.edge(0, turn=turn)  # type: ignore[arg-type]


def test_the_transit_of_a_turned_edge_executes_its_turned_states(m, turned_transit):
    t = turned_transit
    a = t.action
    assert a.turn == t.turn != 0.0 and a.edge == t.edge and "turned" in repr(t)
    e = m.edge(t.edge, turn=t.turn)
    executed = a.q[a.transit_steps :]
    assert np.array_equal(executed, e.q[a.edge_first : a.edge_first + len(executed)])
    assert np.array_equal(t.q_from, lmjx.park_pose(m)) and t.joints == m.robot.joint_names


def test_an_action_runs_from_rest_to_rest_through_its_joint_targets(m, turned_transit):
    """The whole action: from q_from at rest to the edge's last executed state at rest;
    every joint target of the planned-speed part a sample, RAMP / 2 later than planned; the
    time law the planner's (`timelaw.ramped`)."""
    t = turned_transit
    a = t.action
    traj = lmjx.trajectory(t)
    assert traj.at_rest and traj.edge == t.edge and traj.turn == t.turn and traj.joints == m.robot.joint_names
    assert np.array_equal(traj.q[0], t.q_from) and np.array_equal(traj.q[-1], a.q[-1])
    for ends in (traj.qd[[0, -1]], traj.qdd[[0, -1]]):
        assert not ends.any()
    assert traj.t[-1] == pytest.approx(len(a.q) * CONTROL_DT + RAMP, abs=1e-9)
    assert np.allclose(np.diff(traj.t), CONTROL_DT, atol=1e-12)
    mid = (traj.t >= RAMP - 1e-9) & (traj.t <= traj.t[-1] - RAMP + 1e-9)
    k = np.round((traj.t[mid] - RAMP / 2) / CONTROL_DT).astype(int)  # the planned step each sample is
    assert np.abs(traj.q[mid] - a.q[k - 1]).max() < KNOT_TOLERANCE
    # from rest: the first 0.1 s move the arm a fraction of what the planned speed would
    assert np.abs(traj.qd[:5]).max() < 0.5 * np.abs(a.qd[:5]).max()
    # the time law against the planner's own (`ramped`, at its times)
    planned = len(a.q) * CONTROL_DT
    total, r, v = _law(planned, True, True)
    n = 333
    s = time_law(np.arange(1, n + 1) * (total / n), total, r, v)[0]
    assert np.abs(s - ramped(planned, n)).max() < 1e-12
    # the same from the Action and the angles it starts from
    again = lmjx.trajectory(a, q_from=t.q_from, robot=m.robot)
    assert np.array_equal(again.q, traj.q) and np.array_equal(again.qdd, traj.qdd)


def test_its_velocities_and_accelerations_are_its_derivatives(turned_transit):
    """Sampled finely: central differences of the positions are the velocities, the
    trapezoidal integrals of the accelerations and the velocities give back the velocities
    and the positions, central differences of the velocities are the accelerations (within a
    share of the peak: the spline's third derivative jumps at each planned point)."""
    f = lmjx.trajectory(turned_transit, dt=FINE_DT)
    assert np.allclose(np.diff(f.t), FINE_DT, atol=1e-12)
    fd = (f.q[2:] - f.q[:-2]) / (f.t[2:] - f.t[:-2])[:, None]
    assert np.abs(fd - f.qd[1:-1]).max() < VELOCITY_TOLERANCE
    assert np.abs(cumulative_trapezoid(f.qdd, f.t, axis=0, initial=0) - f.qd).max() < INTEGRAL_TOLERANCE
    assert np.abs(cumulative_trapezoid(f.qd, f.t, axis=0, initial=0) + f.q[0] - f.q).max() < INTEGRAL_TOLERANCE
    fdd = (f.qd[2:] - f.qd[:-2]) / (f.t[2:] - f.t[:-2])[:, None]
    assert np.abs(fdd - f.qdd[1:-1]).max() < ACCELERATION_SHARE * np.abs(f.qdd).max()


def test_an_edge_alone_keeps_its_speed_and_its_states(m):
    e = m.edge(5)
    traj = lmjx.trajectory(e, 0.005)
    assert not traj.at_rest and np.array_equal(traj.q[::4], e.q)
    fd = np.diff(traj.q, axis=0) / np.diff(traj.t)[:, None]
    assert np.allclose(fd, traj.qd[:-1], rtol=0, atol=1e-9)
    assert np.allclose(np.diff(traj.qd, axis=0) / np.diff(traj.t)[:, None], traj.qdd[:-1], rtol=0, atol=1e-6)


def test_files_read_back_to_the_same_numbers(turned_transit, tmp_path):
    """JSON as a ROS JointTrajectory (time_from_start whole seconds and nanoseconds) and CSV,
    read with json and csv alone, then with `Trajectory.read`."""
    traj = lmjx.trajectory(turned_transit, dt=0.01)
    traj.write(tmp_path / "a.json")
    traj.write(tmp_path / "a.csv")
    msg = json.loads((tmp_path / "a.json").read_text())
    assert set(msg) == {"header", "joint_names", "points"} and msg["joint_names"] == list(traj.joints)
    p = msg["points"]
    assert set(p[0]) == {"positions", "velocities", "accelerations", "effort", "time_from_start"}
    stamps = [x["time_from_start"] for x in p]
    assert all(type(s["sec"]) is int and type(s["nanosec"]) is int and 0 <= s["nanosec"] < NS for s in stamps)
    assert np.abs(np.array([s["sec"] + s["nanosec"] / NS for s in stamps]) - traj.t).max() <= 0.5e-9
    assert stamps[100] == {"sec": 1, "nanosec": 0}
    for key, want in (("positions", traj.q), ("velocities", traj.qd), ("accelerations", traj.qdd)):
        assert np.array_equal([x[key] for x in p], want), key
    with open(tmp_path / "a.csv") as f:
        rows = list(csv.reader(f))
    nj = len(traj.joints)
    assert rows[0] == ["time_from_start", *traj.joints, *(f"{j}_velocity" for j in traj.joints),
                       *(f"{j}_acceleration" for j in traj.joints)]  # fmt: skip
    table = np.array(rows[1:], float)
    assert np.array_equal(table[:, 0], traj.t) and np.array_equal(table[:, 1 : 1 + nj], traj.q)
    assert np.array_equal(table[:, 1 + 2 * nj :], traj.qdd)
    for name in ("a.json", "a.csv"):
        back = lmjx.Trajectory.read(tmp_path / name)
        assert back.joints == traj.joints and np.array_equal(back.q, traj.q) and np.array_equal(back.qd, traj.qd)
        assert np.abs(back.t - traj.t).max() <= 0.5e-9


def test_joint_names_must_be_the_robots(m, turned_transit):
    t = turned_transit
    names = list(m.robot.joint_names)
    flipped = lmjx.trajectory(t, joint_names=names[::-1])
    plain = lmjx.trajectory(t)
    assert flipped.joints == tuple(names[::-1]) and np.array_equal(flipped.q, plain.q[:, ::-1])
    assert np.array_equal(flipped.qdd, plain.qdd[:, ::-1])
    for bad, message in (
        ([*names[:-1], "elbow"], r"missing \['joint7'\]; not the transit's \['elbow'\]"),
        (names[:-1], r"missing \['joint7'\]"),
        ([*names, names[0]], "a name twice"),
        ("joint1", "give a list of joint names"),
    ):
        with pytest.raises(lmjx.LmjxError, match=message):
            lmjx.trajectory(t, joint_names=bad)
    with pytest.raises(lmjx.LmjxError, match="missing"):
        lmjx.trajectory(t.action, q_from=t.q_from, robot=m.robot, joint_names=names[:3])
    with pytest.raises(lmjx.LmjxError, match="missing"):
        lmjx.trajectory(m.edge(1), joint_names=names[1:])
    own = lmjx.trajectory(t.action, q_from=t.q_from, joint_names=[f"j{k}" for k in range(7)])
    assert own.joints[0] == "j0" and np.array_equal(own.q, plain.q)
