"""One task trial, wired up: map + task + ASM + seed -> planner, simulator, "real" world;
and the choice of the planner's simulator.

The task comes resolved (`lmjx.sim.scenarios.Task`, made once by the entry point); the
planner's scene is built once per simulator, the "real" world's once per trial (its physics
are drawn from the trial's seed).  Seeds: a trial's seed fixes the task's initial layout and
the "real" world's perturbations (so every ASM and failure faces the same trials) and, offset
by the ASM, the planner's own random choices.
"""

from __future__ import annotations

from dataclasses import dataclass

from lmjx.errors import ConfigError
from lmjx.mapfile.read import MapFile
from lmjx.model.robot import Robot
from lmjx.planner.edge_planner import Planner
from lmjx.planner.records import TrialResult
from lmjx.planner.transit import TransitPlanner
from lmjx.sim.cpu import CpuSimulator
from lmjx.sim.realworld import SimulatedRealWorld, real_gains
from lmjx.sim.scenarios import Layout, Task
from lmjx.sim.scene import Physics, build_scene
from lmjx.types import ASMS, SERVOS, PlannerConfig, Simulator

SIMULATORS = ("auto", "cpu", "cpu-near", "gpu")
# Greedy's candidates per decision: what each simulator does well (benchmarks/RESULTS.md)
DEFAULT_CANDIDATES = {"cpu": 32, "cpu-near": 32, "gpu": 1024}


@dataclass
class TrialSetup:
    planner: Planner
    layout: Layout
    world: SimulatedRealWorld
    planner_seed: int


def resolve_simulator(choice: str) -> tuple[str, str]:
    """The simulator `choice` ("auto", "cpu", "cpu-near" or "gpu") stands for here, and why.
    auto: the GPU simulator where a CUDA GPU and MuJoCo Warp are present, else C MuJoCo."""
    if choice not in SIMULATORS:
        raise ConfigError(f"unknown simulator '{choice}'; use {', '.join(SIMULATORS)}")
    if choice in ("auto", "gpu"):
        from lmjx.sim.gpu import warp_problem

        problem = warp_problem()
        if problem is None:
            return "gpu", "a CUDA GPU and MuJoCo Warp are present" if choice == "auto" else "asked for"
        if choice == "gpu":
            raise ConfigError(f"--sim gpu: {problem}; use --sim cpu (or auto)")
        return "cpu", problem
    return choice, "asked for"


def planner_physics(robot: Robot, servo: str = "playback") -> Physics:
    """The planner's physics (`PlannerConfig.servo`): the nominal objects and table, the arm's
    joints tracked by stiff servos with unlimited torque ("playback") or by the robot's own
    servo gains and torque limits ("robot", as the arm's controller tracks them).  Nothing of
    what the planner cannot know (a trial's frictions, masses, capsule sizes) is in either."""
    if servo == "playback":
        return Physics()
    if servo not in SERVOS:
        raise ConfigError(f"unknown servo model '{servo}'; use {' or '.join(SERVOS)}")
    kp, kv = real_gains(robot)
    return Physics(servo_kp=kp, servo_kv=kv, servo_force=tuple(robot.tau_max))


def check_task(robot: Robot, task: Task) -> None:
    """Refuse a task placed for another robot (its positions are scaled for that robot's size)."""
    if task.robot != robot.key:
        raise ConfigError(f"{task.name} is placed for the robot {task.robot}, not {robot.key}; resolve it for "
                          f"{robot.key} (lmjx.sim.scenarios.resolve_task)")  # fmt: skip


def make_simulator(
    robot: Robot,
    task: Task,
    backend: str = "cpu",
    gpu_config=None,
    servo: str = "playback",
) -> Simulator:
    """The planner's simulator for a task: C MuJoCo on all host cores (the whole scene, or
    "cpu-near": the target and its 3 nearest objects), or MuJoCo Warp on the GPU (the whole
    scene; `gpu_config`: its `GpuSimConfig`, e.g. another Warp device), with the servo model
    `servo` (`planner_physics`; the planner passes its own, `PlannerConfig.servo`, "robot" by
    default; "playback" here, the model the simulators' agreement tests and benchmarks
    measure).  `backend` is resolved already (see `resolve_simulator`).  The scene is built
    once, here, and kept by the simulator for every decision of every trial it serves."""
    check_task(robot, task)
    if backend not in ("cpu", "cpu-near", "gpu"):
        raise ConfigError(f"unknown simulator '{backend}'; use cpu, cpu-near or gpu")
    scene = build_scene(robot, task.scenario, planner_physics(robot, servo), fuse_static=backend == "gpu")
    if backend == "gpu":
        from lmjx.sim.gpu import GpuSimulator

        return GpuSimulator(scene, config=gpu_config)
    if backend == "cpu-near":
        return CpuSimulator(scene, k_objects=4, robot=robot)
    return CpuSimulator(scene)


def setup_trial(
    robot: Robot,
    map_file: MapFile,
    task: Task,
    config: PlannerConfig,
    seed: int,
    simulator: Simulator | None = None,
    transits: TransitPlanner | None = None,
    backend: str = "cpu",
) -> TrialSetup:
    """A trial of `task` ready to run.  `simulator`: the planner's, which may serve every
    trial of one task (default: one made here on `backend`, see `make_simulator`, unless the
    ASM is Random, which simulates nothing).  `transits` may be shared by the trials of one
    map (it keeps what it learned about transits through the park pose)."""
    check_task(robot, task)
    assert map_file.reach is not None and map_file.edges is not None
    layout = task.layout(seed)
    if simulator is None and config.asm != "random":
        simulator = make_simulator(robot, task, backend, servo=config.servo)
    planner = Planner(robot, map_file.failure, map_file.reach, map_file.edges, task.scenario, simulator, config,
                      transits)  # fmt: skip
    return TrialSetup(planner, layout, SimulatedRealWorld(robot, seed), seed * 7 + ASMS.index(config.asm))


def run_trial(setup: TrialSetup) -> TrialResult:
    return setup.planner.run(setup.world, setup.layout, setup.planner_seed)
