"""A trial replayed from its record: the executed edges, again, in the trial's "real" world.

A record keeps which edges a trial executed, and its scene (the task: `trial_task`), not the
arm's motion.  Replaying needs no
planner's choice and no simulation of candidates: the world is seeded by the trial
(`SimulatedRealWorld(robot, seed)`: its physics, and the noise of every observation), the
layout by the trial's seed, and the action for an edge is a function of the observation
(`TransitPlanner.actions` for that edge alone gives the action it gives among others).  So
executing the recorded edges one after another (turned about the base joint as recorded:
`turn_deg`), each with its transit from what the world shows then, reproduces the trial,
while the world's state is kept at `FRAME_RATE` frames a second.  Each replayed action is
compared with the record (the target's displacement): a replay on another map, or by another
version of lmjx, shows where it parts from the record.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import mujoco
import numpy as np

from lmjx.errors import ConfigError
from lmjx.mapfile.read import MapFile
from lmjx.model.robot import Robot
from lmjx.sim.scenarios import Task
from lmjx.types import CONTROL_DT
from lmjx.view.trialrecord import TrialRecord, trial_task

FRAME_RATE = 10.0  # frames kept per second of execution
AGREE_M = 0.00015  # the record's displacements are rounded to 0.1 mm: a replayed action agrees within that


@dataclass
class ActionMark:
    """One executed action, in frames and in space."""

    index: int  # 0-based
    edge: int
    route: str
    start: int  # first frame of the transit
    edge_start: int  # first frame of the edge
    end: int  # last frame of the action
    target_before: np.ndarray  # (3,) the target's true position before [m]
    target_after: np.ndarray  # (3,) after
    transit_path: np.ndarray  # (n, 3) the edge's interaction point along the transit
    edge_path: np.ndarray  # (m, 3) ... along the edge
    moved_m: float  # the target's displacement in the replay
    recorded_moved_m: float | None  # ... in the record
    recorded_route: str | None = None  # the transit's route in the record
    agrees: bool = True  # this action and every one before it did what the record says


@dataclass
class Replay:
    record: TrialRecord
    model: mujoco.MjModel  # the world's scene: arm, table, objects, goal
    robot_qpos: np.ndarray  # (nq,) the arm's qpos addresses in it
    target_body: int
    frames: np.ndarray  # (T, model.nq) qpos
    times: np.ndarray  # (T,) [s] of execution
    actions: list[ActionMark] = field(default_factory=list)
    task: Task | None = None  # the task it ran (its scenario: what is on the table)
    scene_matches: bool = True  # the task's definition has the digest the record gives

    @property
    def complete(self) -> bool:
        """Every recorded action was replayed (else one found no transit in the replay)."""
        return len(self.actions) == len(self.record.steps)

    def first_disagreement(self) -> ActionMark | None:
        return next((a for a in self.actions if not a.agrees), None)


def replay(robot: Robot, map_file: MapFile, record: TrialRecord, say: Callable[[str], None] | None = None) -> Replay:
    """Execute the record's edges again in its trial's world; see the module docstring."""
    from lmjx.planner.transit import TransitPlanner, after_executing
    from lmjx.planner.turned import TurnedEdges, turn_axis
    from lmjx.sim.realworld import SimulatedRealWorld
    from lmjx.sim.scenarios import sample_layout

    if map_file.edges is None:
        raise ConfigError(f"{map_file.path} has no edges; the trial {record.key} ran on a map with edges")
    if map_file.failure.spec != record.failure:
        raise ConfigError(
            f"{map_file.path} holds failure {map_file.failure.spec}; trial {record.key} ran on {record.failure}"
        )
    bundle = map_file.edges
    for s in record.steps:
        if not 0 <= int(s["edge"]) < bundle.n_edges:
            raise ConfigError(f"trial {record.key} executed edge {s['edge']}, which {map_file.path} does not have "
                              f"({bundle.n_edges:,} edges): give the map it ran on with --map")  # fmt: skip
    task, matches = trial_task(record, robot)
    if not matches and say is not None:
        say(f"the scene of trial {record.key} differs from the one its record describes (its digest; another version "
            "of lmjx, or an edited record): the replay may part from the record")  # fmt: skip
    sc = task.scenario
    layout = sample_layout(sc, record.seed)
    world = SimulatedRealWorld(robot, record.seed)
    # a GPU run's transits were checked by the batched JAX kernel, a CPU run's by C MuJoCo: the same here
    transits = TransitPlanner(robot, map_file.failure, batched=record.batched)
    transits.late_start = record.late_start
    frames: list[np.ndarray] = []
    times: list[float] = []
    step_time = [0.0]

    def keep(m: mujoco.MjModel, d: mujoco.MjData) -> None:
        step_time[0] += m.opt.timestep
        if not times or step_time[0] - times[-1] >= 1.0 / FRAME_RATE - 1e-9:
            frames.append(d.qpos.copy())
            times.append(step_time[0])

    obs = world.reset(layout, transits.park)
    assert world.scene is not None and world.data is not None
    scene = world.scene
    frames.append(world.data.qpos.copy())
    times.append(0.0)
    world.on_step = keep
    trail = obs.robot_q[None].copy()
    came_from = None
    target_body = int(scene.obj_body[0])
    marks: list[ActionMark] = []
    for k, s in enumerate(record.steps):
        e = int(s["edge"])
        transits.set_scene(sc, obs.objects)
        turn = int(s.get("turn_deg", 0))  # an edge executed turned about the base joint (`turn_edges`)
        axis = turn_axis(robot, map_file.failure) if turn else None
        if axis is not None:
            view = TurnedEdges(bundle, np.array([e]), np.radians([turn]), axis)
            acts = transits.actions(view, np.array([0]), obs.robot_q, 1, came_from, trail)
        else:
            acts = transits.actions(bundle, np.array([e]), obs.robot_q, 1, came_from, trail)
        if not acts:
            if say is not None:
                say(f"action {k + 1} (edge {e}) has no feasible transit in the replay: the replay stops there")
            break
        a = acts[0]
        before = world.data.xpos[target_body].copy()
        start = len(frames)
        obs = world.execute(a)
        path = _site_path(robot, a.q, int(bundle.site[e]))
        n_transit = a.transit_steps
        edge_start = start + round(n_transit * CONTROL_DT * FRAME_RATE)
        recorded = s.get("target_moved_m")
        same = recorded is None or abs(float(obs.target_moved_m) - float(recorded)) <= AGREE_M
        same = same and s.get("transit_route", a.route) == a.route and (not marks or marks[-1].agrees)
        marks.append(
            ActionMark(
                index=k,
                edge=e,
                route=a.route,
                start=start,
                edge_start=min(edge_start, len(frames) - 1),
                end=len(frames) - 1,
                target_before=before,
                target_after=world.data.xpos[target_body].copy(),
                transit_path=path[: n_transit + 1],
                edge_path=path[n_transit:],
                moved_m=float(obs.target_moved_m),
                recorded_moved_m=None if recorded is None else float(recorded),
                recorded_route=s.get("transit_route"),
                agrees=same,
            )
        )
        came_from, trail = after_executing(a, trail, bundle.q_start.dtype)
        if say is not None:
            say(f"replayed action {k + 1} of {len(record.steps)} (edge {e}, {a.route})")
    world.on_step = None
    return Replay(record, scene.model, scene.robot_qpos, target_body, np.array(frames), np.array(times), marks, task,
                  matches)  # fmt: skip


def frame_at(text: str, n_frames: int) -> int:
    """The frame of `text`: "start", "end" or a time in seconds (clamped to the trial)."""
    if text == "start":
        return 0
    if text == "end":
        return n_frames - 1
    try:
        seconds = float(text)
    except ValueError:
        raise ConfigError(f"--at {text!r}: give start, end or a time in seconds") from None
    if not np.isfinite(seconds):
        raise ConfigError(f"--at {text!r}: a time in seconds is a finite number")
    return int(np.clip(round(seconds * FRAME_RATE), 0, n_frames - 1))


def _site_path(robot: Robot, q: np.ndarray, site: int) -> np.ndarray:
    """(T, 3) world positions of `site` along the joint targets q (T, nq)."""
    m = robot.mj
    d = mujoco.MjData(m)
    adr = np.array([m.joint(n).qposadr[0] for n in robot.joint_names])
    out = np.empty((len(q), 3))
    for i, x in enumerate(q):
        d.qpos[adr] = x
        mujoco.mj_kinematics(m, d)
        out[i] = d.site_xpos[site]
    return out
