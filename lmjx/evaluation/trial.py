"""One task trial, wired up: map + scenario + ASM + seed -> planner, simulator, "real" world;
and the choice of the planner's simulator.

Seeds: a trial's seed fixes the scenario's initial layout and the "real" world's
perturbations (so every ASM and failure faces the same trials) and, offset by the ASM, the
planner's own random choices.
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
from lmjx.sim.scenarios import Layout, sample_layout, scenario
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


def make_simulator(
    robot: Robot,
    scenario_number: int,
    backend: str = "cpu",
    tasks: str = "paper",
    gpu_config=None,
    servo: str = "playback",
) -> Simulator:
    """The planner's simulator for a scenario: C MuJoCo on all host cores (the whole scene,
    or "cpu-near": the target and its 3 nearest objects), or MuJoCo Warp on the GPU (the
    whole scene; `gpu_config`: its `GpuSimConfig`, e.g. another Warp device), with the servo
    model `servo` (`planner_physics`; the planner passes its own, `PlannerConfig.servo`, "robot"
    by default; "playback" here, the model the simulators' agreement tests and benchmarks
    measure).  `backend` is resolved already (see `resolve_simulator`)."""
    sc = scenario(scenario_number, robot.profile.task_scale, tasks)
    physics = planner_physics(robot, servo)
    if backend == "gpu":
        from lmjx.sim.gpu import GpuSimulator

        return GpuSimulator(build_scene(robot, sc, physics, fuse_static=True), config=gpu_config)
    if backend == "cpu-near":
        return CpuSimulator(build_scene(robot, sc, physics), k_objects=4, robot=robot)
    if backend != "cpu":
        raise ConfigError(f"unknown simulator '{backend}'; use cpu, cpu-near or gpu")
    return CpuSimulator(build_scene(robot, sc, physics))


def setup_trial(
    robot: Robot,
    map_file: MapFile,
    scenario_number: int,
    config: PlannerConfig,
    seed: int,
    simulator: Simulator | None = None,
    transits: TransitPlanner | None = None,
    tasks: str = "paper",
) -> TrialSetup:
    """A trial ready to run, on scenario `scenario_number` of the task set `tasks`.
    `transits` may be shared by the trials of one map (it keeps what it learned about
    transits through the park pose)."""
    sc = scenario(scenario_number, robot.profile.task_scale, tasks)
    assert map_file.reach is not None and map_file.edges is not None
    sim = simulator or (
        make_simulator(robot, scenario_number, tasks=tasks, servo=config.servo) if config.asm != "random" else None
    )
    planner = Planner(robot, map_file.failure, map_file.reach, map_file.edges, sc, sim, config, transits)
    return TrialSetup(
        planner, sample_layout(sc, seed), SimulatedRealWorld(robot, seed), seed * 7 + ASMS.index(config.asm)
    )


def run_trial(setup: TrialSetup) -> TrialResult:
    return setup.planner.run(setup.world, setup.layout, setup.planner_seed)
