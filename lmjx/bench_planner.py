"""`lmjx bench` planner section: Greedy's scoring of candidate actions, MJX on the accelerator
against C MuJoCo (`mujoco.rollout`) on all host cores, on the same actions from the same
observed state of Scenario 3.

Figures: seconds to simulate and score N candidates (median of repeats, compile apart),
physics steps per second, and how far the two simulators agree (target end positions,
scores, and whether they would pick the same action).  Also the time of one whole Greedy
decision on the CPU (transits + simulation + scoring) with the planner's default 32
candidates, the figure the issue's CPU goal is about.
"""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path

import numpy as np

from .actions import TransitPlanner
from .errors import ConfigError
from .mapfile import load_map
from .planner import Planner, PlannerConfig, edges_over_target, score
from .robot import Robot
from .scenarios import sample_layout, scenario
from .scene import build_scene, object_qpos
from .simulate import CpuSimulator


def _candidates(robot: Robot, map_path: str, scenario_number: int, n: int, seed: int):
    mf = load_map(map_path)
    if mf.edges is None or mf.reach is None:
        raise ConfigError(f"{map_path} has no kinodynamic map (edges); build it with lmjx build-map")
    sc = scenario(scenario_number)
    layout = sample_layout(sc, seed)
    scene = build_scene(robot, sc)
    objects = object_qpos(scene, layout.poses)
    tp = TransitPlanner(robot, mf.failure)
    edges = edges_over_target(mf.edges, mf.reach, objects[0, :2], float(sc.target.half[0]), 0.01)
    order = np.random.default_rng(seed).permutation(edges)
    acts = []
    for e in order:
        a = tp.action(mf.edges, int(e), tp.park)
        if a is not None:
            acts.append(a)
        if len(acts) == n:
            break
    if not acts:
        raise ConfigError(f"{map_path}: no feasible action over the target in scenario {scenario_number}")
    while len(acts) < n:  # fewer distinct edges than asked: repeat (the work is what is timed)
        acts.append(acts[len(acts) % max(1, len(acts))])
    return mf, sc, scene, objects, tp, acts


def bench_planner(
    robot: Robot,
    map_path: str,
    candidates: int = 256,
    repeats: int = 3,
    use_mjx: bool = False,
    scenario_number: int = 3,
    seed: int = 0,
) -> dict:
    if not Path(map_path).exists():
        raise ConfigError(f"no map at {map_path}; build one with lmjx build-map --failure case2 --out {map_path}")
    mf, sc, scene, objects, tp, acts = _candidates(robot, map_path, scenario_number, candidates, seed)
    q0 = tp.park
    out: dict = {
        "scenario": scenario_number,
        "failure": mf.failure.spec,
        "candidates": candidates,
        "action_seconds_mean": float(np.mean([a.duration for a in acts])),
    }

    def timed(sim) -> tuple[float, np.ndarray, int]:
        sim.simulate(q0, objects, acts[:1])  # builds scenes / compiles
        times, final = [], None
        for _ in range(repeats):
            sim.steps_run = 0
            t0 = time.perf_counter()
            final = sim.simulate(q0, objects, acts)
            times.append(time.perf_counter() - t0)
        return statistics.median(times), final, sim.steps_run

    cpu = CpuSimulator(scene)
    t, final_cpu, steps = timed(cpu)
    s_cpu = score(sc, robot, final_cpu)
    out["cpu"] = {
        "what": f"C MuJoCo mujoco.rollout, {cpu.threads} threads ({os.cpu_count()} cores), whole scene "
        f"({scene.n_objects} objects, box table)",
        "seconds": t,
        "steps": steps,
        "steps_per_s": steps / t,
    }

    def agreement(final: np.ndarray) -> dict:
        finite = np.isfinite(final).all(axis=(1, 2))  # a simulation that blew up scores as lost
        final = np.where(finite[:, None, None], final, 1e3)
        s = score(sc, robot, final)
        d = np.hypot(*(final[:, 0, :2] - final_cpu[:, 0, :2]).T)[finite]
        stats = {"median": float(np.median(d)), "p90": float(np.quantile(d, 0.9))} if len(d) else None
        return {
            "non_finite": int((~finite).sum()),
            "target_end_diff_m": stats,
            "same_choice": bool(np.argmin(s_cpu) == np.argmin(s)),
            # how much worse (by the whole-scene simulation) the action it picks is than the best
            "choice_gap_m": float(s_cpu[np.argmin(s)] - s_cpu.min()),
        }

    near = CpuSimulator(scene, k_objects=4, robot=robot)
    t, final_near, steps = timed(near)
    out["cpu_near"] = {
        "what": f"C MuJoCo mujoco.rollout, {near.threads} threads, the target and its 3 nearest objects",
        "seconds": t,
        "steps": steps,
        "steps_per_s": steps / t,
        **agreement(final_near),
    }
    if use_mjx:
        from .simulate_mjx import MjxSimulator

        mjx_sim = MjxSimulator(robot, sc, batch=candidates)
        t0 = time.perf_counter()
        mjx_sim.simulate(q0, objects, acts)  # compiles
        first = time.perf_counter() - t0
        t, final_mjx, steps = timed(mjx_sim)
        out["mjx"] = {
            "what": f"MuJoCo MJX, batch {mjx_sim.batch}, the target and its {mjx_sim.k - 1} nearest objects, "
            "plane table",
            "first_call_s": first,
            "seconds": t,
            "steps": steps,
            "steps_per_s": steps / t,
            **agreement(final_mjx),
        }
        out["speedup_mjx_vs_cpu"] = out["cpu"]["seconds"] / t
    fastest = min((k for k in ("cpu", "cpu_near", "mjx") if k in out), key=lambda k: out[k]["seconds"])
    out["fastest"] = {"simulator": fastest, "seconds": out[fastest]["seconds"]}
    # one whole Greedy decision on this host's CPU, the planner's defaults (32 candidates)
    cfg = PlannerConfig(asm="greedy")
    planner = Planner(robot, mf.failure, mf.reach, mf.edges, sc, CpuSimulator(scene), cfg)
    from .executor import Observation

    obs = Observation(q0, objects, 0.0)
    times = []
    for r in range(repeats):
        t0 = time.perf_counter()
        planner.choose(obs, np.random.default_rng(seed + r))
        times.append(time.perf_counter() - t0)
    out["cpu_greedy_action"] = {"candidates": cfg.greedy_candidates, "seconds": statistics.median(times)}
    return out
