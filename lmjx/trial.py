"""One task trial, wired up: map + scenario + ASM + seed -> planner, simulator, "real" world.

Seeds: a trial's seed fixes the scenario's initial layout and the "real" world's
perturbations (so every ASM and failure faces the same trials) and, offset by the ASM, the
planner's own random choices.
"""

from __future__ import annotations

from dataclasses import dataclass

from .errors import ConfigError
from .executor import SimulatedRealWorld
from .mapfile import MapFile
from .planner import ASMS, Planner, PlannerConfig, TrialResult
from .robot import Robot
from .scenarios import Layout, sample_layout, scenario
from .scene import build_scene
from .simulate import CpuSimulator, Simulator


@dataclass
class TrialSetup:
    planner: Planner
    layout: Layout
    world: SimulatedRealWorld
    planner_seed: int


SIMULATORS = ("cpu", "cpu-near", "mjx")


def make_simulator(robot: Robot, scenario_number: int, backend: str = "cpu") -> Simulator:
    """The planner's simulator: C MuJoCo on all host cores (the whole scene, or "cpu-near":
    the target and its 3 nearest objects), or MJX on the accelerator.  Measured in
    benchmarks/RESULTS.md: C MuJoCo on the host cores is both faster and closer to the
    whole scene than MJX at the planner's batch sizes, so it is the default everywhere."""
    sc = scenario(scenario_number)
    if backend not in SIMULATORS:
        raise ConfigError(f"unknown simulator '{backend}'; use {', '.join(SIMULATORS)}")
    if backend == "cpu-near":
        return CpuSimulator(build_scene(robot, sc), k_objects=4, robot=robot)
    if backend == "mjx":
        from .simulate_mjx import MjxSimulator

        return MjxSimulator(build_scene(robot, sc))
    return CpuSimulator(build_scene(robot, sc))


def setup_trial(
    robot: Robot,
    map_file: MapFile,
    scenario_number: int,
    config: PlannerConfig,
    seed: int,
    simulator: Simulator | None = None,
) -> TrialSetup:
    sc = scenario(scenario_number)
    assert map_file.reach is not None and map_file.edges is not None
    sim = simulator or make_simulator(robot, scenario_number)
    planner = Planner(robot, map_file.failure, map_file.reach, map_file.edges, sc, sim, config)
    return TrialSetup(
        planner, sample_layout(sc, seed), SimulatedRealWorld(robot, seed), seed * 7 + ASMS.index(config.asm)
    )


def run_trial(setup: TrialSetup) -> TrialResult:
    return setup.planner.run(setup.world, setup.layout, setup.planner_seed)
