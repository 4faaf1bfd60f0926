"""lmjx: keep a robot arm with locked joints useful, with whole-body non-prehensile actions.

Public API (everything else is internal).  Wherever it takes a robot, a name ('panda', the
default; 'ur5e'), an MJCF's path or a Robot will do; wherever it takes a failure, a spec
('none', one of the robot's presets such as 'case2', or 'J2=0.3,J4=-1.5') or a Failure.

  load_robot(name_or_path)          a Robot ('panda', 'ur5e' or an MJCF's path; docs/ROBOTS.md)
  robots(), check_robot(path)       the shipped robots; what an MJCF lacks to be an lmjx robot
  parse_failure(spec, robot)        a Failure: 'none', a preset or 'J2=0.3,J4=-1.5'
  ReachConfig, reach_config(robot)  a Reach-Ability map's settings (a robot's defaults)
  reach_map(failure, config, robot) the Reach-Ability map (paper Algorithm 1) -> ReachResult
  write_reach_map(path, result)     write it to a map file (what `lmjx reach --out` writes)
  build_map(failure, robot, out)    a map file: reach map + edge bundle (`lmjx build-map`) -> MapBuild
  load_map(path)                    read and validate a map file (schema: maps/README.md) -> MapFile
  plan_task(map_file, scenario)     one task, closed loop (`lmjx plan`, Algorithm 3) -> PlanResult
  load_scene(path, robot)           a scene file (docs/SCENES.md), checked, as a Task; shipped_scene(n, tasks)

For a planner of one's own (docs/API.md):
  MapFile.edges_over(region, turned) -> ids (, turns)    the edges acting over a region, and with turned their
                                                         copies turned about the arm's base joint (the planner's)
  MapFile.edge(i, turn) -> Edge                          one edge's states, turned by `turn` [rad] or not
  transit(robot, scene, q_from, edge) -> Transit         the collision-checked transit to an edge, or why none
  trajectory(transit or edge, dt) -> Trajectory          a whole action from rest to rest (or an edge alone):
                                                         positions, velocities, accelerations; .write(csv, json)
  simulate(scene, state, actions)                        where each object ends, batched (CPU or GPU)
  park_pose(map_file)                                    where a trial's arm starts
  Executor, SimulatedRealWorld                           where actions run: a real robot's interface and
                                                         its simulated reference implementation
  Action, Observation, Layout                            what an executor takes and reports; a trial's
                                                         initial poses (Task.layout(seed), or your own)
  Poses are position then quaternion (w, x, y, z), MuJoCo's order; order="xyzw" where the API
  takes or gives them (transit, simulate) uses ROS's (x, y, z, w).
  use_device('cpu' | 'gpu')         where JAX runs (`--device`), before the first computation
  LmjxError                         base class of errors caused by user input

Example (small settings for a quick try):

    >>> import lmjx
    >>> res = lmjx.reach_map("case2", lmjx.ReachConfig(cell=0.05), robot="panda")
    >>> res                                            # doctest: +SKIP
    ReachResult('case2': 24 x 20 cells of 5 cm, PM 0.000 m^2, NPM+PM 0.698 m^2; 3.1 s on cpu)

Names are imported on first use, so that `import lmjx` (and `lmjx --help`) stays light.
"""

from __future__ import annotations

import importlib
from typing import Any

from lmjx.runtime.cpucode import pin_cpu_code

pin_cpu_code()  # (before JAX starts: the same map from the same command on every x86-64 CPU)

__version__ = "0.1.0"

_EXPORTS = {
    "Failure": "model.failure",
    "parse_failure": "model.failure",
    "LmjxError": "errors",
    "ReachConfig": "reach.reachability",
    "ReachResult": "reach.reachability",
    "reach_config": "reach.reachability",
    "reach_map": "reach.reachability",
    "MapFile": "mapfile.read",
    "load_map": "mapfile.read",
    "write_reach_map": "mapfile.write",
    "Robot": "model.robot",
    "load_robot": "model.robot",
    "robots": "model.robot",
    "check_robot": "model.robot",
    "MapBuild": "api",
    "PlanResult": "api",
    "build_map": "api",
    "plan_task": "api",
    "use_device": "api",
    "Task": "sim.scenarios",
    "Layout": "sim.scenarios",
    "load_scene": "sim.scenefile",
    "shipped_scene": "sim.scenefile",
    "Edge": "mapfile.trajectory",
    "Trajectory": "mapfile.trajectory",
    "trajectory": "toolkit",
    "Transit": "toolkit",
    "transit": "toolkit",
    "simulate": "toolkit",
    "park_pose": "toolkit",
    "Action": "types",
    "Observation": "types",
    "Executor": "types",
    "SimulatedRealWorld": "sim.realworld",
}

__all__ = ["__version__", *sorted(_EXPORTS)]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module 'lmjx' has no attribute '{name}'")


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
