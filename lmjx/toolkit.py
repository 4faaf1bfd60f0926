"""lmjx's parts for another planner: the collision-checked transit to an edge, turned or not
(`transit`), the batched simulation of candidate actions (`simulate`), an edge's or a whole
action's joint trajectory for a robot's controller (`trajectory`: an action from rest to rest,
on the planner's time law), and where a trial's arm starts (`park_pose`).  With
`MapFile.edges_over`, `MapFile.edge`, a scene (`load_scene`) and an executor
(`lmjx.types.Executor`; the simulated "real" world `SimulatedRealWorld` is its reference
implementation), a planner of one's own chooses the edges and lmjx does the rest;
docs/API.md has an example of each.  Every mistake in what they are given is a one-line
`ConfigError`.

Poses are position then quaternion (w, x, y, z), MuJoCo's order; `order="xyzw"` takes and
gives them in the order of ROS and scipy (x, y, z, w) instead.

These wrap what lmjx's own planner uses (`lmjx.planner.transit.TransitPlanner`,
`lmjx.planner.trial.make_simulator`), each made once per map or scene and kept, so that
calling them decision after decision costs what the planner's calls cost.  Nothing here
chooses actions.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from lmjx.errors import ConfigError
from lmjx.mapfile.trajectory import (
    Edge,
    Trajectory,
    check_period,
    edge_trajectory,
    in_joint_order,
    sample_times,
)
from lmjx.runtime.interrupt import interruptible
from lmjx.types import CONTROL_DT, Action

if TYPE_CHECKING:
    from lmjx.mapfile.read import MapFile
    from lmjx.model.robot import Robot
    from lmjx.sim.scenarios import Task
    from lmjx.types import Observation

# `transit`'s reasons when there is none: `TransitPlanner.actions`' tally keys, in words
REASONS = {
    "start_blocked": "start blocked: the edge's start is within the margins of an object, or in the table or the "
    "arm itself",
    "edge_unusable": "edge unusable: it does not reach into the target's box, or a fixed obstacle cuts it short",
    "no_transit": "no transit: every way to its start (straight, through the park pose, the roadmap) collides",
}
QUAT_ORDERS = ("wxyz", "xyzw")  # a pose's quaternion: (w, x, y, z), MuJoCo's and lmjx's; (x, y, z, w), ROS's
SERVOS = ("robot", "playback")  # `simulate`'s ways the arm tracks its joint targets
# an Action's first joint target lies within this of where it starts [rad] (a control step at
# 10 rad/s): `trajectory` refuses a q_from further off (the joint angles of another start)
FIRST_STEP = 0.2
SIMULATORS_KEPT = 4  # `simulate`'s simulators kept (the latest scenes)
_SIMULATORS: OrderedDict[tuple, Any] = OrderedDict()
_PLANNERS_ATTR = "_toolkit_transits"  # kept on the map's bundle: robot key -> its TransitPlanner


@dataclass(frozen=True, eq=False)
class Transit:
    """What `transit` found for one edge: the action (the transit's joint targets then the
    edge's, every CONTROL_DT = 0.02 s: ready for `simulate`, `Executor.execute` and
    `trajectory`) and the way it went, or None and why not; where it starts (`q_from`),
    the robot's joint names and the edge's turn."""

    edge: int
    action: Action | None = field(repr=False)
    route: str  # "direct", "park" (through the park pose), "roadmap", "escape+..." (none: "")
    reason: str  # "" when there is an action; else why there is none (`REASONS`)
    turn: float = 0.0  # [rad] the edge turned about the base joint by this (`MapFile.edge(i, turn=...)`)
    q_from: np.ndarray | None = field(default=None, repr=False)  # (nq,) the joint angles it starts from
    joints: tuple[str, ...] = field(default=(), repr=False)  # the robot's joint names (the columns of q)

    def __bool__(self) -> bool:
        return self.action is not None

    @property
    def q(self) -> np.ndarray | None:
        """The transit's joint targets alone (T, nq), or None."""
        return None if self.action is None else self.action.q[: self.action.transit_steps]

    def __repr__(self) -> str:
        edge = f"edge {self.edge}" + (f" turned {self.turn:+.4f} rad" if self.turn else "")
        if self.action is None:
            return f"Transit({edge}: none; {self.reason.split(':')[0]})"
        a = self.action
        return (f"Transit({edge}: {self.route}, {a.transit_steps} transit steps then {a.edge_states} of the "
                f"edge's states, {a.duration:.2f} s)")  # fmt: skip


def _order(order: object) -> str:
    """A quaternion order, checked: "wxyz" (MuJoCo's) or "xyzw" (ROS's)."""
    if order not in QUAT_ORDERS:
        raise ConfigError(f"order: a quaternion's order is 'wxyz' (MuJoCo's, lmjx's) or 'xyzw' (ROS's), got {order!r}")
    return str(order)


def poses_wxyz(poses: np.ndarray, order: str) -> np.ndarray:
    """Poses (..., 7) (position, quaternion in `order`) with their quaternions as (w, x, y, z)."""
    return poses if order == "wxyz" else np.concatenate([poses[..., :3], poses[..., 6:7], poses[..., 3:6]], axis=-1)


def poses_in(poses: np.ndarray, order: str) -> np.ndarray:
    """Poses (..., 7) with (w, x, y, z) quaternions as (position, quaternion in `order`)."""
    return poses if order == "wxyz" else np.concatenate([poses[..., :3], poses[..., 4:7], poses[..., 3:4]], axis=-1)


def _array(value: object, what: str, shape: str) -> np.ndarray:
    """`value` as a float64 array, or a one-line ConfigError saying what to give."""
    try:
        return np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"{what}: give {shape}, got {type(value).__name__}") from None


def _task(scene: object, where: str) -> Task:
    from lmjx.sim.scenarios import Task

    if not isinstance(scene, Task):
        raise ConfigError(f"{where}: the scene is a Task (lmjx.load_scene), got {type(scene).__name__}")
    return scene


def _objects(task: Task, objects: np.ndarray | None, order: str = "wxyz") -> np.ndarray:
    """Object poses (n, 7) (position, quaternion (w, x, y, z)): `objects` as (n, 7) (their
    quaternions in `order`), or as (n, 3) x, y, yaw resting on the table, or None for the
    scene's nominal poses."""
    from lmjx.sim.scene import yaw_quat

    movable = task.scenario.movable
    if objects is None:
        objects = np.array([[b.x, b.y, b.yaw] for b in movable])
    shapes = f"({len(movable)}, 7) poses (x, y, z, quaternion) or ({len(movable)}, 3) x, y, yaw, target first"
    obj = _array(objects, "objects", shapes)
    if obj.ndim != 2 or len(obj) != len(movable) or obj.shape[1] not in (3, 7):
        raise ConfigError(f"objects: give {shapes}; got shape {obj.shape}")
    if not np.isfinite(obj).all():
        raise ConfigError("objects: a pose is not finite (NaN or infinite); give the objects' poses")
    if obj.shape[1] == 7:
        obj = poses_wxyz(obj, order)
        norm = np.linalg.norm(obj[:, 3:], axis=1)
        if np.any(np.abs(norm - 1.0) > 1e-3):
            raise ConfigError(f"objects: the quaternions' norms are {np.round(norm, 4).tolist()}, not 1; give unit "
                              f"quaternions ({'w, x, y, z' if order == 'wxyz' else 'x, y, z, w'})")  # fmt: skip
        return obj
    out = np.zeros((len(obj), 7))
    out[:, :2] = obj[:, :2]
    out[:, 2] = [b.zc for b in movable]
    out[:, 3:] = np.stack([yaw_quat(y) for y in obj[:, 2]])
    return out


def _check(robot: Robot, task: Task) -> None:
    from lmjx.planner.trial import check_task

    check_task(robot, task)


@interruptible
def transit(
    robot: Robot | str,
    scene: Task,
    q_from: np.ndarray,
    edge: Edge,
    objects: np.ndarray | None = None,
    acting: bool = True,
    after: Action | None = None,
    order: str = "wxyz",
) -> Transit:
    """The collision-checked way from the joint angles `q_from` (nq,) to the start of `edge`
    (from `MapFile.edge`, turned about the base joint or not), then the edge, in `scene` (a
    `Task`, e.g. `load_scene`'s) with its movable objects at `objects` ((n, 7) poses as an
    `Observation` gives them, position and quaternion (w, x, y, z), or (x, y, z, w) with
    `order="xyzw"`; or (n, 3) x, y, yaw; default: the nominal poses): as lmjx's planner
    builds an action.  The transit keeps clear of the table, the arm itself and the objects'
    margins (1 cm from movable boxes, 2 cm from fixed ones), going straight where it can,
    else through the park pose, else along a roadmap over the map's edge starts; a turned
    edge's executed states are checked against the base and the table too.  `acting`: refuse
    an edge whose arm does not reach into the target's box (lmjx's rule: an edge over the
    target that misses it wastes an action).  `after`: the action executed last (the arm then
    first retreats along its edge).  Returns a `Transit`: its `action` (None when there is
    none; `action.turn` the edge's turn) and `reason`."""
    from lmjx.mapfile.turned import TurnedEdges
    from lmjx.model.robot import as_robot
    from lmjx.planner.transit import TransitPlanner

    rob = as_robot(robot)
    task = _task(scene, "transit")
    _check(rob, task)
    if not isinstance(edge, Edge):
        raise ConfigError(f"transit: give an edge from MapFile.edge, got {type(edge).__name__}")
    m: MapFile | None = edge.source
    if m is None or m.edges is None:
        raise ConfigError("transit: give an edge from MapFile.edge (it knows its map)")
    if m.robot is not None and m.robot.key != rob.key:
        raise ConfigError(f"transit: the edge is of a map of the robot {m.robot.key}, not {rob.key}")
    if not isinstance(acting, bool | np.bool_):
        raise ConfigError(f"transit: acting is True or False, got {acting!r}")
    if after is not None and not isinstance(after, Action):
        raise ConfigError(f"transit: after is the Action executed last (or None), got {type(after).__name__}")
    q = _array(q_from, "q_from", f"the {rob.nq} joint angles of {rob.key}")
    if q.shape != (rob.nq,) or not np.isfinite(q).all():
        raise ConfigError(f"q_from: give the {rob.nq} joint angles of {rob.key}, got shape {q.shape}")
    placed = _objects(task, objects, _order(order))
    planners = m.edges.__dict__.setdefault(_PLANNERS_ATTR, {})
    if rob.key not in planners:
        planners[rob.key] = TransitPlanner(rob, m.failure)
    tp = planners[rob.key]
    tp.set_scene(task.scenario, placed, acting=acting)
    came_from = None if after is None else after.q[after.transit_steps :].astype(m.edges.q_start.dtype)
    bundle: Any = m.edges
    if edge.turn:  # a view of the one edge turned, as the planner offers turned copies
        axis = m.turn_axis()
        assert axis is not None  # (a turned Edge exists only about one)
        bundle = TurnedEdges(m.edges, np.array([edge.index]), np.array([edge.turn]), axis)
    acts = tp.actions(bundle, np.array([0 if edge.turn else edge.index]), q, 1, came_from)
    found = dict(turn=edge.turn, q_from=q.copy(), joints=rob.joint_names)
    if acts:
        return Transit(edge.index, acts[0], acts[0].route, "", **found)
    why = next((k for k in ("start_blocked", "edge_unusable", "no_transit") if tp.last_tally.get(k)), "no_transit")
    return Transit(edge.index, None, "", REASONS[why], **found)


@interruptible
def simulate(
    scene: Task, state: Observation, actions: list[Action], sim: str = "cpu", servo: str = "robot", order: str = "wxyz"
) -> np.ndarray:
    """Where each object ends (len(actions), n, 7: position, quaternion (w, x, y, z), or
    (x, y, z, w) with `order="xyzw"`; the target first) after each of `actions` from `state`
    (an `Observation`: the arm's joint angles and the objects' poses, their quaternions in
    `order`), each simulated on its own copy of the scene and left to settle for 0.5 s, in
    one batch: `sim` "cpu" (C MuJoCo on every core), "cpu-near" (the target and its 3 nearest
    objects), "gpu" (MuJoCo Warp on a CUDA GPU) or "auto"; `servo`: how the arm tracks its
    joint targets ("robot": the robot's own servo gains and torque limits, the planner's
    default; "playback").  The simulator is the planner's (nominal physics: the scene's
    masses and frictions, never the "real" world's), made once per scene and kept."""
    from lmjx.model.robot import load_robot
    from lmjx.planner.trial import make_simulator, resolve_simulator

    task = _task(scene, "simulate")
    if not isinstance(sim, str):
        raise ConfigError(f"simulate: sim is 'cpu', 'cpu-near', 'gpu' or 'auto', got {sim!r}")
    if servo not in SERVOS:
        raise ConfigError(f"simulate: servo is {' or '.join(repr(s) for s in SERVOS)}, got {servo!r}")
    order = _order(order)
    if not hasattr(state, "robot_q") or not hasattr(state, "objects"):
        raise ConfigError(f"simulate: state is an Observation (robot_q, objects), got {type(state).__name__}")
    if isinstance(actions, Action) or not isinstance(actions, list | tuple):
        raise ConfigError(f"simulate: actions is a list of Actions, got {type(actions).__name__}")
    if not all(isinstance(a, Action) for a in actions):
        bad = next(a for a in actions if not isinstance(a, Action))
        raise ConfigError(f"simulate: actions is a list of Actions (Transit.action), got a {type(bad).__name__}")
    robot = load_robot(task.robot)
    q = _array(state.robot_q, "state.robot_q", f"the {robot.nq} joint angles of {robot.key}")
    if q.shape != (robot.nq,) or not np.isfinite(q).all():
        raise ConfigError(f"state.robot_q: give the {robot.nq} joint angles of {robot.key}, got shape {q.shape}")
    for a in actions:
        if np.ndim(a.q) != 2 or np.shape(a.q)[1] != robot.nq or np.shape(a.qd) != np.shape(a.q):
            raise ConfigError(f"simulate: an action's q and qd are (T, {robot.nq}) joint targets of {robot.key}, got "
                              f"{np.shape(a.q)} and {np.shape(a.qd)}")  # fmt: skip
    objects = _objects(task, state.objects, order)
    backend, _ = resolve_simulator(sim)
    key = (task, backend, servo)
    if key not in _SIMULATORS:
        if len(_SIMULATORS) >= SIMULATORS_KEPT:
            _SIMULATORS.popitem(last=False)
        _SIMULATORS[key] = make_simulator(robot, task, backend, servo=servo)
    _SIMULATORS.move_to_end(key)
    acts = list(actions)
    if not acts:
        return np.zeros((0, len(task.scenario.movable), 7))
    return poses_in(_SIMULATORS[key].simulate(q, objects, acts), order)


def park_pose(map_file: MapFile) -> np.ndarray:
    """The joint angles (nq,) a trial starts from on `map_file`'s robot and failure: the arm
    raised clear of the table, its locked joints at their angles (what lmjx's planner
    resets the executor to)."""
    from lmjx.mapfile.read import MapFile
    from lmjx.planner.clearance import park_pose as park

    if not isinstance(map_file, MapFile) or map_file.robot is None:
        raise ConfigError(f"park_pose: give a map (lmjx.load_map), got {type(map_file).__name__}")
    return park(map_file.robot, map_file.failure)


def trajectory(
    what: Edge | Transit | Action,
    dt: float | None = None,
    q_from: np.ndarray | None = None,
    joint_names: list[str] | tuple[str, ...] | None = None,
    robot: Robot | str | None = None,
) -> Trajectory:
    """The joint trajectory of `what`, sampled every `dt` seconds, for a robot's controller
    (`Trajectory.write`: CSV, or JSON as a ROS JointTrajectory):

    - an `Edge` (`MapFile.edge`): the edge alone at its own speed, as the map stores it
      (`lmjx.mapfile.trajectory.edge_trajectory`; dt default: the map's 0.02 s);
    - a `Transit` (`lmjx.transit`, one with an action), or an `Action` with `q_from`, the
      joint angles it starts from: the whole action, from rest to rest (`action_trajectory`:
      the transit from where the arm stands to the edge's start, then the edge; dt default
      CONTROL_DT = 0.02 s).

    `joint_names`: the controller's joint names, in its order: they must be the robot's
    (the edge's, the transit's, or `robot`'s for an Action) and the columns follow them.  An
    Action does not name its joints: give `robot` (e.g. the map's) or `joint_names`."""
    if dt is not None:
        check_period(dt)
    if isinstance(what, Edge):
        if q_from is not None:
            raise ConfigError("trajectory: an Edge's trajectory starts at its first state; q_from is for an Action")
        if robot is not None:
            from lmjx.model.robot import as_robot

            in_joint_order(edge_trajectory(what, dt), list(as_robot(robot).joint_names), "the edge")
        return in_joint_order(edge_trajectory(what, dt), joint_names, "the edge")
    if isinstance(what, Transit):
        if what.action is None:
            why = what.reason.split(":")[0]
            raise ConfigError(f"trajectory: the transit to edge {what.edge} has no action ({why}); take a true one")
        start = what.q_from if q_from is None else q_from
        traj = action_trajectory(what.action, start, CONTROL_DT if dt is None else float(dt), what.joints)
        return in_joint_order(traj, joint_names, "the transit")
    if isinstance(what, Action):
        if q_from is None:
            raise ConfigError("trajectory: an Action starts where the arm stands: give q_from=... (the joint angles it "
                              "starts from), or pass the Transit itself")  # fmt: skip
        nq = np.shape(what.q)[1] if np.ndim(what.q) == 2 else -1
        if robot is not None:
            from lmjx.model.robot import as_robot

            names = as_robot(robot).joint_names
            traj = action_trajectory(what, q_from, CONTROL_DT if dt is None else float(dt), names)
            return in_joint_order(traj, joint_names, "the robot")
        if joint_names is None:
            raise ConfigError("trajectory: an Action does not name its joints: give robot=... (e.g. the map's "
                              "m.robot) or joint_names=[...]")  # fmt: skip
        if isinstance(joint_names, str) or not isinstance(joint_names, list | tuple) or len(joint_names) != nq:
            raise ConfigError(f"joint_names: give the action's {nq} joint names, got {joint_names!r}")
        return action_trajectory(what, q_from, CONTROL_DT if dt is None else float(dt), tuple(joint_names))
    raise ConfigError(f"trajectory: give an Edge (MapFile.edge), a Transit (lmjx.transit) or an Action with q_from, "
                      f"got {type(what).__name__}")  # fmt: skip


def action_trajectory(action: Action, q_from: np.ndarray, dt: float, joints: tuple[str, ...]) -> Trajectory:
    """An action's joint trajectory (`Action`: joint targets q (T, nq), one every CONTROL_DT
    from q_from (nq,)), from rest to rest, sampled every dt [s]: the path through q_from and
    the targets (a cubic spline in the planned time u, through every target at its planned
    time, C2) followed on the planner's time law (`lmjx.planner.timelaw`): a half-cosine rise
    from rest over RAMP, the planned speed, a mirror-image fall to rest at the last target.
    Velocities and accelerations are the derivatives of that motion (0 at both ends); where
    dt divides CONTROL_DT every target of the planned-speed part is a sample, RAMP / 2 later
    than planned."""
    from scipy.interpolate import CubicSpline

    from lmjx.planner.timelaw import _law

    q = _array(action.q, "action.q", "(T, nq) joint targets")
    start = _array(q_from, "q_from", f"the {len(joints)} joint angles the action starts from")
    if q.ndim != 2 or len(q) == 0 or q.shape[1] != len(joints) or not np.isfinite(q).all():
        raise ConfigError(f"trajectory: the action's q is (T, {len(joints)}) finite joint targets, got shape {q.shape}")
    if start.shape != (len(joints),) or not np.isfinite(start).all():
        raise ConfigError(
            f"q_from: give the {len(joints)} joint angles the action starts from, got shape {start.shape}"
        )
    step = np.abs(q[0] - start)
    if step.max() > FIRST_STEP:
        j = int(np.argmax(step))
        raise ConfigError(f"q_from is {step[j]:.3f} rad from the action's first joint target ({joints[j]}); give the "
                          "joint angles the action starts from (a Transit carries them)")  # fmt: skip
    path = np.concatenate([start[None], q])  # (T + 1, nq) at planned times 0, dt, ..., T dt
    planned = len(q) * CONTROL_DT
    total, r, v = _law(planned, True, True)
    tau = sample_times(total, dt)
    s, s1, s2 = time_law(tau, total, r, v)
    spline = CubicSpline(np.arange(len(path)) * CONTROL_DT, path, axis=0, bc_type="natural")
    u = np.clip(planned * s, 0.0, planned)
    d1, rate = spline(u, 1), (planned * s1)[:, None]
    pos = spline(u)
    vel = d1 * rate
    acc = spline(u, 2) * rate**2 + d1 * (planned * s2)[:, None]
    pos[0], pos[-1] = path[0], path[-1]
    vel[[0, -1]] = 0.0
    acc[[0, -1]] = 0.0
    return Trajectory(tau, pos, vel, acc, tuple(joints), edge=action.edge, turn=float(action.turn), at_rest=True)


def time_law(tau: np.ndarray, total: float, r: float, v: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fraction s of a run done at times tau (N,) [s], and its first and second
    derivatives, on `lmjx.planner.timelaw`'s law with a rise and a fall ((total, r, v) of its
    `_law`): s rises from rest along a half cosine over r, goes on at rate v, falls to rest
    over the last r (`timelaw.ramped` gives the same s at its own times)."""

    def up(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # x seconds into a rise
        a = np.pi * x / r
        return 0.5 * v * (x - r / np.pi * np.sin(a)), 0.5 * v * (1 - np.cos(a)), 0.5 * v * np.pi / r * np.sin(a)

    s, s1, s2 = v * (tau - r / 2), np.full(len(tau), v), np.zeros(len(tau))
    rise, fall = tau < r, tau > total - r
    a, a1, a2 = up(np.clip(tau, 0.0, r))
    b, b1, b2 = up(np.clip(total - tau, 0.0, r))
    s, s1, s2 = np.where(rise, a, s), np.where(rise, a1, s1), np.where(rise, a2, s2)
    s, s1, s2 = np.where(fall, 1.0 - b, s), np.where(fall, b1, s1), np.where(fall, -b2, s2)
    return np.clip(s, 0.0, 1.0), s1, s2
