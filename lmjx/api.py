"""What `lmjx build-map` and `lmjx plan` do, as Python functions with the commands' defaults.

`build_map` builds a failure's map file (the Reach-Ability map and the kinodynamic edge
bundle, paper Algorithms 1-2) and `plan_task` runs one task closed loop on a map (Algorithm
3).  Each takes names where the command line does (a robot's name or MJCF path, a failure
spec such as 'case2' or 'J2=0.3,J4=-1.5') and returns a result with a one-line `repr` and
the command's `--json` summary (`summary()`).  They print nothing (progress bars on stderr
only with progress=True) and raise `LmjxError` for a user's mistake.  This module only
wires the library together: the work is in `lmjx.edges.stream` and `lmjx.planner.trial`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lmjx import checks
from lmjx.errors import ConfigError
from lmjx.mapfile.read import MapFile, load_map
from lmjx.model.failure import Failure, as_failure
from lmjx.model.robot import Robot, as_robot
from lmjx.planner.records import StepRecord, TrialResult
from lmjx.runtime.interrupt import interruptible
from lmjx.sim.scenarios import Task

DEVICES = ("auto", "cpu", "gpu")


def use_device(device: str = "auto") -> str:
    """Run JAX's kernels on `device` ("auto": a GPU if JAX sees one, else the CPU; "cpu";
    "gpu"), as the commands' `--device`; returns the platform JAX uses.  JAX picks its
    platform once per process: asking for another after the first computation raises
    ConfigError (start a fresh process, or set JAX_PLATFORMS before anything runs)."""
    if device not in DEVICES:
        raise ConfigError(f"unknown device '{device}'; use {', '.join(DEVICES)}")
    import jax

    if device != "auto":
        wanted = "cpu" if device == "cpu" else "cuda"
        with contextlib.suppress(Exception):  # JAX may refuse once its backends exist: checked below
            jax.config.update("jax_platforms", wanted)
    try:
        platform = jax.default_backend()
    except Exception as e:  # JAX raises RuntimeError or AssertionError without a GPU
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ConfigError(f"no {device.upper()} is available to JAX ({first}); use device='auto' or 'cpu'") from None
    on_gpu = platform in ("gpu", "cuda", "rocm")
    if (device == "cpu" and platform != "cpu") or (device == "gpu" and not on_gpu):
        raise ConfigError(
            f"JAX already runs on {platform} in this process; choose device='{device}' before the first "
            f"computation (or set JAX_PLATFORMS={'cpu' if device == 'cpu' else 'cuda'})"
        )
    return platform


def default_map_path(failure: Failure, robot: Robot) -> Path:
    """Where `lmjx build-map` writes a map without --out: maps/<failure>.h5 for the Panda,
    maps/<robot>/<failure>.h5 for another robot (relative to the working directory)."""
    safe = "".join(c if c.isalnum() or c in "-." else "_" for c in failure.spec)
    return Path(robot.maps_dir) / f"{safe}.h5"


@dataclass
class MapBuild:
    """What `build_map` did: the map file written and the figures `lmjx build-map --json` prints."""

    path: Path
    robot: Robot
    failure: Failure
    seed: int
    edges: dict[str, Any]  # the edge bundle's figures: edges_sampled, edges_valid, rejected, seconds, ...
    reach: dict[str, Any] = field(default_factory=dict)  # the reach map's: cell_m, area_m2, ... ({} on processes > 0)
    built: bool = True  # False: `path` already held this map, which was kept (its figures are those of its build)

    def __repr__(self) -> str:
        e = self.edges
        areas = ""
        if self.reach:
            a = self.reach["area_m2"]
            areas = f"PM {a['pm']:.3f} m^2, NPM+PM {a['npm_pm']:.3f} m^2; "
        kept = "" if self.built else "; already there, kept"
        return (
            f"MapBuild({str(self.path)!r}: {self.robot.key}, failure {self.failure.spec!r}; {areas}"
            f"{e['edges_valid']:,} edges kept of {e['edges_sampled']:,} sampled; on {e['device']}{kept})"
        )

    def summary(self) -> dict[str, Any]:
        """The JSON summary of `lmjx build-map --json`."""
        s = self.edges
        stages = s.get("compile_by_stage", {})
        top = ("bytes_per_state", "raw_bytes_per_state", "compile_by_stage", "compiled_for_later")
        return {
            "robot": self.robot.key,
            "failure": self.failure.spec,
            "out": str(self.path),
            "seed": self.seed,
            "built": self.built,  # false: the map was already there, kept
            # compiling, or loading compiled programs from the cache: the wall time during which
            # some program compiled (stages compiled side by side count once: never above the
            # build's wall time), the stages' own seconds below
            "compile_seconds": round(s.get("compile_wall_seconds", sum(stages.values())), 4),
            "compile_seconds_by_stage": stages,
            # other failures' programs compiled for later builds (None: not asked for)
            "compiled_for_later": s.get("compiled_for_later"),
            "reach": self.reach,
            "edges": {k: v for k, v in s.items() if k not in top},
            "bytes_per_state": round(s.get("bytes_per_state", 0.0), 2),
            "raw_bytes_per_state": round(s.get("raw_bytes_per_state", 0.0), 2),
            "device": s["device"],
            "devices": s.get("devices"),
            "processes": s.get("processes"),
        }

    def load(self, lazy: bool | None = None) -> MapFile:
        """The map file, opened (`load_map`)."""
        return load_map(self.path, self.robot, lazy=lazy)


@interruptible
def build_map(
    failure: Failure | str,
    robot: Robot | str | Path | None = None,
    out: str | Path | None = None,
    edges: int | None = None,
    seed: int = 0,
    cell: float = 0.02,
    chunk: int | None = None,
    device: str = "auto",
    sharded: bool = True,
    yes: bool = False,
    progress: bool = False,
    say: Any = None,
    compile_presets: bool | None = None,
    overwrite: bool = False,
) -> MapBuild:
    """Build a failure's map file, as `lmjx build-map` does: the Reach-Ability map (cells of
    `cell` metres), then `edges` sampled edges (default: 10,000 on a CPU, 100,000 on a GPU;
    only valid ones are kept), written to `out` (default maps/<failure>.h5, another robot's
    maps/<robot>/<failure>.h5; schema: maps/README.md).  The same seed gives the same map.
    An interrupted build leaves its finished chunks in `<out>.partial`, and the same call
    continues it.  A map already at `out` built with the same robot, failure, parameters and
    seed is kept (nothing is computed; the result's `built` is False); any other file there
    is replaced only with `overwrite` (else OutputPathError).  `robot`: a Robot, a shipped
    robot's name or an MJCF's path (default the Panda); `device`: see `use_device`;
    `chunk`: edges computed at a time (not part of the result); `yes`: start even when the
    preflight estimates more than a day of work;
    `say`: where the preflight's lines go (default: nowhere); `progress`: bars on stderr;
    `compile_presets`: also compile the programs of the robot's other preset failures for
    later builds on this machine, where the cache lacks them (None: on accelerators only).

    Example (small settings for a quick try: 10 cm cells, 200 edges; seconds on a CPU once
    compiled):

    >>> import lmjx
    >>> b = lmjx.build_map("case2", out="maps/case2_small.h5", cell=0.1, edges=200, seed=0)
    >>> b.edges["edges_valid"] > 0
    True
    """
    from lmjx.edges.stream import build_map as stream_map
    from lmjx.mapfile.bundle import BundleConfig
    from lmjx.reach.reachability import reach_config

    seed = checks.seed(seed)
    cell = checks.finite_number(cell, "cell", above=0.0)
    if edges is not None:
        checks.whole_number(edges, "edges", 1)
    if chunk is not None:
        checks.whole_number(chunk, "chunk", 1)
    use_device(device)
    import jax

    robot = as_robot(robot)
    failure = as_failure(failure, robot)
    reach_cfg = reach_config(robot, cell=cell, seed=seed)
    bundle_cfg = BundleConfig(edges=edges, seed=seed, build_chunk=chunk, interaction_points=robot.default_ips)
    path = Path(out) if out is not None else default_map_path(failure, robot)
    s = stream_map(
        path, failure, reach_cfg, bundle_cfg, robot, progress=progress, sharded=sharded, yes=yes,
        say=say or (lambda line: None), compile_presets=compile_presets, overwrite=overwrite,
    )  # fmt: skip
    kept = bool(s.get("kept"))
    result = MapBuild(path, robot, failure, seed, dict(s), built=not kept)
    if jax.process_index() == 0:
        # the reach map's figures (and a kept map's edge figures) from the file; a map just
        # built has its edges' figures in `s`, and its edges are not read again (a 5,000,000-edge
        # map's index alone is 128 M edge ids)
        with load_map(path, robot, lazy=True, with_edges=kept) as m:
            assert m.reach is not None and (m.edges is not None or not kept)
            rs = m.reach.summary()
            result.reach = {k: rs[k] for k in ("cell_m", "area_m2", "area_raw_m2", "seconds", "compile_seconds")}
            if kept:  # the figures of the build that wrote it
                result.edges = m.edges.summary() | {"bytes_per_state": float(m.edges_attrs.get("bytes_per_state", 0.0))}
    return result


@dataclass
class PlanResult:
    """One task, planned and executed (`plan_task`): how it ended and every step.
    `execution_s` is the robot's simulated time (the motions' duration), not wall time."""

    robot: str
    failure: str
    scenario: int
    tasks: str
    task: str  # what the task is called ("scenario 1", a scene file's name)
    asm: str
    seed: int
    simulator: str  # "cpu", "cpu-near", "gpu", or "none" (Random simulates nothing)
    simulator_reason: str
    simulator_description: str | None
    candidates: int | None  # Greedy's actions simulated per decision (None for the others)
    asm_settings: dict[str, Any]
    trial: TrialResult
    # the task's scene (`lmjx.sim.scenefile.scene_record`): a shipped scenario's number and task
    # set, else its scene file's text, with its definition's digest: the record replays alone
    scene: dict[str, Any] = field(default_factory=dict)

    @property
    def success(self) -> bool:
        return self.trial.success

    @property
    def actions(self) -> int:
        return self.trial.actions

    @property
    def steps(self) -> list[StepRecord]:
        return self.trial.steps

    @property
    def planning_s(self) -> float:
        return self.trial.planning_s

    @property
    def execution_s(self) -> float:
        return self.trial.execution_s

    @property
    def final_distance(self) -> float:
        return self.trial.final_distance

    @property
    def reason(self) -> str:
        return self.trial.reason

    def __repr__(self) -> str:
        t = self.trial
        end = "success" if t.success else "failure"
        return (
            f"PlanResult({self.failure!r}, {self.task} ({self.tasks} tasks), {self.asm}, "
            f"seed {self.seed}: "
            f"{end} ({t.reason}) after {t.actions} action{'' if t.actions == 1 else 's'}; "
            f"planning {t.planning_s:.1f} s, robot time "
            f"{t.execution_s:.1f} s; target {t.final_distance * 100:.1f} cm from the goal's centre)"
        )

    def summary(self) -> dict[str, Any]:
        """The JSON summary of `lmjx plan --json`."""
        return {
            "robot": self.robot,
            "failure": self.failure,
            "tasks": self.tasks,
            "scenario": self.scenario,
            "task": self.task,
            "scene": self.scene,
            "asm": self.asm,
            "seed": self.seed,
            "simulator": self.simulator,
            "simulator_reason": self.simulator_reason,
            "simulator_description": self.simulator_description,
            "candidates": self.candidates,
            "asm_settings": self.asm_settings,
            **self.trial.summary(),
            "steps": [s.summary() for s in self.trial.steps],
        }


@interruptible
def plan_task(
    map_file: str | Path | MapFile,
    scenario: int | Task | str | Path,
    asm: str = "greedy",
    seed: int = 0,
    tasks: str = "paper",
    max_actions: int | None = None,
    candidates: int | None = None,
    asm_settings: str | None = None,
    when_stuck: str | None = None,
    late_start: bool | None = None,
    push_weight: float | None = None,
    rescore_top: int | None = None,
    rescore_draws: int | None = None,
    servo: str | None = None,
    sim: str = "auto",
    robot: Robot | str | Path | None = None,
    failure: Failure | str | None = None,
    render: str | Path | None = None,
    say: Any = None,
    planner: Mapping[str, Any] | str | Path | None = None,
    on_action: Callable[[int, int, StepRecord], None] | None = None,
) -> PlanResult:
    """Run one task closed loop, as `lmjx plan` does: push the target cube of `scenario`
    (1: clutter, 2: tunnel, 3: eleven boxes) of the task set `tasks` ("paper" or "hard")
    into its goal region with the edges of `map_file` (a map file's path, or a `MapFile`),
    choosing each action with `asm` ("random", "lazy" or "greedy").  `scenario` may also be a
    `Task` resolved for the map's robot (`lmjx.sim.scenarios.resolve_task`, `load_scene`;
    `tasks` is then its own), or a scene file's path (docs/SCENES.md: checked as `load_scene`
    checks it).  Whatever the task, a goal region with no reachable cell of the map under it
    is refused before anything is simulated.  `seed` fixes the layout, the "real" world's
    physics and the planner's choices.
    `max_actions`: the budget (default: the task set's); `candidates`: Greedy's simulated
    actions per decision (default 1,024 with the GPU simulator, 32 on the CPU);
    `planner`: the planner's levers, keys of `PlannerConfig` (`lmjx plan --help-levers`), as a
    mapping or a TOML file's path, e.g. {"asm_settings": "paper"} for the ASMs as the paper
    states them; the keywords `asm_settings` to `servo` set the key of their name and win over
    `planner`'s; `sim`: the planner's simulator ("auto", "cpu", "cpu-near", "gpu"); `robot`:
    read the map with this robot (default: the one it names); `failure`: refuse a map built
    for another failure; `render`: write the trial as a .png frame strip, .gif or .mp4 (needs
    OpenGL, e.g. MUJOCO_GL=osmesa); `say`: where the simulator's choice goes, once the
    arguments are checked (default: nowhere); `on_action(k, budget, step)`: called after each
    executed action (the k-th of at most `budget`; its `StepRecord`, with `latency_s` and
    `distance_after`), as `lmjx plan` prints its progress.

    Example (the map `make run` writes; Random simulates nothing, so this takes seconds):

    >>> import lmjx
    >>> r = lmjx.plan_task("maps/case2.h5", scenario=1, asm="random", seed=0, max_actions=2)
    >>> r.actions <= 2 and len(r.steps) >= r.actions
    True
    """
    from lmjx.planner.levers import check_levers, planner_config, read_levers
    from lmjx.planner.trial import SIMULATORS, check_task, resolve_simulator, run_trial, setup_trial
    from lmjx.runtime.fileio import check_writable
    from lmjx.sim.scenarios import resolve_task
    from lmjx.sim.scenecheck import check_goal
    from lmjx.sim.scenefile import load_scene, scene_record
    from lmjx.types import ASMS

    if asm not in ASMS:
        raise ConfigError(f"unknown action selection mechanism '{asm}'; use {', '.join(ASMS)}")
    if sim not in SIMULATORS:
        raise ConfigError(f"unknown simulator '{sim}'; use {', '.join(SIMULATORS)}")
    seed = checks.seed(seed)
    for name, value in (("max_actions", max_actions), ("candidates", candidates)):
        if value is not None:
            checks.whole_number(value, name, 1)
    levers = planner if isinstance(planner, Mapping) else read_levers(planner) if planner is not None else {}
    given = {"asm_settings": asm_settings, "when_stuck": when_stuck, "late_start": late_start,
             "push_weight": push_weight, "rescore_top": rescore_top, "rescore_draws": rescore_draws, "servo": servo,
             "max_actions": max_actions, "greedy_candidates": candidates}  # fmt: skip
    levers = check_levers({**levers, **{k: v for k, v in given.items() if v is not None}})
    m = map_file if isinstance(map_file, MapFile) else load_map(map_file, robot)
    assert m.robot is not None
    rob = m.robot
    # the task, once, for everything below
    if isinstance(scenario, Task):
        task = scenario
    elif isinstance(scenario, str | Path):
        task = load_scene(scenario, rob)
    else:
        task = resolve_task(scenario, rob, tasks)
    if failure is not None and as_failure(failure, rob).locked != m.failure.locked:
        wanted = failure.spec if isinstance(failure, Failure) else failure
        raise ConfigError(f"{m.path} holds a map of failure {m.failure.spec}, not {wanted}")
    if m.edges is None or m.reach is None:
        extra = "" if rob.key == "panda" else f" --robot {rob.key}"
        raise ConfigError(f"{m.path} has no edges; build it with: lmjx build-map{extra} --failure {m.failure.spec}")
    check_task(rob, task)
    check_goal(task, m.reach, task.name)
    if render is not None:
        from lmjx.sim.render import check_render_path

        check_render_path(str(render))
        check_writable(render, "rendering")
    if asm == "random":
        sim_name, why = "none", "random does not simulate"
    else:
        sim_name, why = resolve_simulator(sim)
    config = planner_config(asm, sim_name, levers)
    if say is not None and sim_name != "none":  # once the settings are checked
        say(f"simulator {sim_name} ({why})")
    setup = setup_trial(rob, m, task, config, seed, backend=sim_name)
    setup.planner.on_action = on_action
    simulator = setup.planner.sim
    recorder = None
    if render is not None:
        from lmjx.sim.render import Recorder

        recorder = Recorder(setup.world)
    trial = run_trial(setup)
    if recorder is not None:
        recorder.write(str(render))
    return PlanResult(
        robot=rob.key,
        failure=m.failure.spec,
        scenario=task.number,
        tasks=task.tasks,
        task=task.name,
        asm=asm,
        seed=seed,
        simulator=sim_name,
        simulator_reason=why,
        simulator_description=simulator.description if simulator is not None else None,
        candidates=config.greedy_candidates if asm == "greedy" else None,
        asm_settings=config.settings(),
        trial=trial,
        scene=scene_record(task, rob),
    )
