"""lmjx's parts for another planner: the collision-checked transit to an edge (`transit`), the
batched simulation of candidate actions (`simulate`), and where a trial's arm starts
(`park_pose`).  With `MapFile.edges_over`, `MapFile.edge`, `trajectory` (lmjx.mapfile.trajectory),
a scene (`load_scene`) and an executor (`lmjx.types.Executor`; the simulated "real" world
`SimulatedRealWorld` is its reference implementation), a planner of one's own chooses the
edges and lmjx does the rest; docs/API.md has an example of each.

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
from lmjx.runtime.interrupt import interruptible

if TYPE_CHECKING:
    from lmjx.mapfile.read import MapFile
    from lmjx.mapfile.trajectory import Edge
    from lmjx.model.robot import Robot
    from lmjx.sim.scenarios import Task
    from lmjx.types import Action, Observation

# `transit`'s reasons when there is none: `TransitPlanner.actions`' tally keys, in words
REASONS = {
    "start_blocked": "start blocked: the edge's start is within the margins of an object, or in the table or the "
    "arm itself",
    "edge_unusable": "edge unusable: it does not reach into the target's box, or a fixed obstacle cuts it short",
    "no_transit": "no transit: every way to its start (straight, through the park pose, the roadmap) collides",
}
SIMULATORS_KEPT = 4  # `simulate`'s simulators kept (the latest scenes)
_SIMULATORS: OrderedDict[tuple, Any] = OrderedDict()
_PLANNERS_ATTR = "_toolkit_transits"  # kept on the map's bundle: robot key -> its TransitPlanner


@dataclass(frozen=True, eq=False)
class Transit:
    """What `transit` found for one edge: the action (the transit's joint targets then the
    edge's, every CONTROL_DT = 0.02 s: ready for `simulate` and `Executor.execute`) and the
    way it went, or None and why not."""

    edge: int
    action: Action | None = field(repr=False)
    route: str  # "direct", "park" (through the park pose), "roadmap", "escape+..." (none: "")
    reason: str  # "" when there is an action; else why there is none (`REASONS`)

    def __bool__(self) -> bool:
        return self.action is not None

    @property
    def q(self) -> np.ndarray | None:
        """The transit's joint targets alone (T, nq), or None."""
        return None if self.action is None else self.action.q[: self.action.transit_steps]

    def __repr__(self) -> str:
        if self.action is None:
            return f"Transit(edge {self.edge}: none; {self.reason.split(':')[0]})"
        a = self.action
        return (f"Transit(edge {self.edge}: {self.route}, {a.transit_steps} transit steps then {a.edge_states} of the "
                f"edge's states, {a.duration:.2f} s)")  # fmt: skip


def _objects(task: Task, objects: np.ndarray | None) -> np.ndarray:
    """Object poses (n, 7) (position, quaternion): `objects` as (n, 7), or as (n, 3) x, y, yaw
    resting on the table, or None for the scene's nominal poses."""
    from lmjx.sim.scene import yaw_quat

    movable = task.scenario.movable
    if objects is None:
        objects = np.array([[b.x, b.y, b.yaw] for b in movable])
    obj = np.asarray(objects, np.float64)
    if obj.ndim != 2 or len(obj) != len(movable) or obj.shape[1] not in (3, 7):
        raise ConfigError(f"objects: give ({len(movable)}, 7) poses (x, y, z, quaternion) or ({len(movable)}, 3) x, y, "
                          f"yaw, target first; got shape {obj.shape}")  # fmt: skip
    if obj.shape[1] == 7:
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
) -> Transit:
    """The collision-checked way from the joint angles `q_from` (nq,) to the start of `edge`
    (from `MapFile.edge`), then the edge, in `scene` (a `Task`, e.g. `load_scene`'s) with its
    movable objects at `objects` ((n, 7) poses as an `Observation` gives them, or (n, 3) x, y,
    yaw; default: the nominal poses): as lmjx's planner builds an action.  The transit keeps
    clear of the table, the arm itself and the objects' margins (1 cm from movable boxes,
    2 cm from fixed ones), going straight where it can, else through the park pose, else
    along a roadmap over the map's edge starts.  `acting`: refuse an edge whose arm does not
    reach into the target's box (lmjx's rule: an edge over the target that misses it wastes
    an action).  `after`: the action executed last (the arm then first retreats along its
    edge).  Returns a `Transit`: its `action` (None when there is none) and `reason`."""
    from lmjx.model.robot import as_robot
    from lmjx.planner.transit import TransitPlanner

    rob = as_robot(robot)
    _check(rob, scene)
    m: MapFile | None = edge.source
    if m is None or m.edges is None:
        raise ConfigError("transit: give an edge from MapFile.edge (it knows its map)")
    planners = m.edges.__dict__.setdefault(_PLANNERS_ATTR, {})
    if rob.key not in planners:
        planners[rob.key] = TransitPlanner(rob, m.failure)
    tp = planners[rob.key]
    q = np.asarray(q_from, np.float64)
    if q.shape != (rob.nq,) or not np.isfinite(q).all():
        raise ConfigError(f"q_from: give the {rob.nq} joint angles of {rob.key}, got shape {q.shape}")
    tp.set_scene(scene.scenario, _objects(scene, objects), acting=acting)
    came_from = None if after is None else after.q[after.transit_steps :].astype(m.edges.q_start.dtype)
    acts = tp.actions(m.edges, np.array([edge.index]), q, 1, came_from)
    if acts:
        return Transit(edge.index, acts[0], acts[0].route, "")
    why = next((k for k in ("start_blocked", "edge_unusable", "no_transit") if tp.last_tally.get(k)), "no_transit")
    return Transit(edge.index, None, "", REASONS[why])


@interruptible
def simulate(
    scene: Task, state: Observation, actions: list[Action], sim: str = "cpu", servo: str = "robot"
) -> np.ndarray:
    """Where each object ends (len(actions), n, 7: position, quaternion; the target first)
    after each of `actions` from `state` (an `Observation`: the arm's joint angles and the
    objects' poses), each simulated on its own copy of the scene and left to settle for 0.5 s,
    in one batch: `sim` "cpu" (C MuJoCo on every core), "cpu-near" (the target and its 3
    nearest objects), "gpu" (MuJoCo Warp on a CUDA GPU) or "auto"; `servo`: how the arm
    tracks its joint targets ("robot": the robot's own servo gains and torque limits, the
    planner's default; "playback").  The simulator is the planner's (nominal physics: the
    scene's masses and frictions, never the "real" world's), made once per scene and kept."""
    from lmjx.model.robot import load_robot
    from lmjx.planner.trial import make_simulator, resolve_simulator

    backend, _ = resolve_simulator(sim)
    key = (scene, backend, servo)
    if key not in _SIMULATORS:
        if len(_SIMULATORS) >= SIMULATORS_KEPT:
            _SIMULATORS.popitem(last=False)
        _SIMULATORS[key] = make_simulator(load_robot(scene.robot), scene, backend, servo=servo)
    _SIMULATORS.move_to_end(key)
    acts = list(actions)
    if not acts:
        return np.zeros((0, len(scene.scenario.movable), 7))
    return _SIMULATORS[key].simulate(np.asarray(state.robot_q, np.float64), _objects(scene, state.objects), acts)


def park_pose(map_file: MapFile) -> np.ndarray:
    """The joint angles (nq,) a trial starts from on `map_file`'s robot and failure: the arm
    raised clear of the table, its locked joints at their angles (what lmjx's planner
    resets the executor to)."""
    from lmjx.planner.clearance import park_pose as park

    assert map_file.robot is not None
    return park(map_file.robot, map_file.failure)
