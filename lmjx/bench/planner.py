"""`lmjx bench` planner section: Greedy's scoring of candidate actions, the GPU simulator
(MuJoCo Warp) against C MuJoCo (`mujoco.rollout`) on all host cores, on the same actions
from the same observed state of Scenario 3, in one run.

Figures, per candidate count: seconds to simulate the candidates (median of repeats;
capture and compilation apart), physics steps per second, and how closely each simulator
agrees with C MuJoCo's whole scene (target end positions: median and 90th percentile
difference; whether it picks the same action; how much worse, by C MuJoCo's score, the
action it picks is: the choice gap).  Also C MuJoCo with only the target's nearest objects
(the `cpu-near` approximation), and one whole Greedy decision (transits + simulation +
scoring) with the simulator's default candidate count.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np

from lmjx.errors import ConfigError
from lmjx.mapfile.read import load_map
from lmjx.model.robot import Robot
from lmjx.planner.edge_planner import Planner, edges_over_target
from lmjx.planner.scoring import score
from lmjx.planner.transit import TransitPlanner
from lmjx.planner.trial import DEFAULT_CANDIDATES, make_simulator
from lmjx.runtime.cores import usable_cores
from lmjx.sim.cpu import CpuSimulator
from lmjx.sim.scenarios import resolve_task, sample_layout, scenario
from lmjx.sim.scene import build_scene, object_qpos
from lmjx.types import Observation, PlannerConfig

LONG_REFERENCE = 1024  # C MuJoCo above this many candidates is timed once (it takes tens of seconds)


def candidate_actions(robot: Robot, map_path: str, scenario_number: int, n: int, seed: int, planner_scene: bool = True):
    """Up to n Greedy candidates from the park pose for a scenario's seeded layout (repeated
    when fewer distinct edges pass over the target): the map, scenario, scene, objects,
    transit planner and actions.  `planner_scene`: as the planner offers them (transits and
    edge starts clear of the scene, edges that act on the target); False: checked against the
    table and the arm only (actions for comparing simulators, which need not be offered)."""
    mf = load_map(map_path, robot)
    if mf.edges is None or mf.reach is None:
        raise ConfigError(f"{map_path} has no kinodynamic map (edges); build it with lmjx build-map")
    sc = scenario(scenario_number, robot.profile.task_scale, "hard")
    layout = sample_layout(sc, seed)
    scene = build_scene(robot, sc)
    objects = object_qpos(scene, layout.poses)
    tp = TransitPlanner(robot, mf.failure)
    if planner_scene:
        tp.set_scene(sc, objects)
    edges = edges_over_target(mf.edges, mf.reach, objects[0, :2], float(sc.target.half[0]), 0.01)
    order = np.random.default_rng(seed).permutation(edges)
    acts = tp.actions(mf.edges, order, tp.park, n)
    if not acts:
        raise ConfigError(f"{map_path}: no feasible action over the target in scenario {scenario_number}")
    acts = [acts[i % len(acts)] for i in range(n)]  # fewer distinct edges than asked: repeat (the work is timed)
    return mf, sc, scene, objects, tp, acts


def agreement(sc, robot: Robot, final: np.ndarray, reference: np.ndarray) -> dict:
    """How `final` (n, objects, 7) agrees with the reference simulation of the same actions."""
    finite = np.isfinite(final).all(axis=(1, 2))  # a simulation that blew up scores as lost
    s_ref = score(sc, robot, reference)
    s = score(sc, robot, np.where(finite[:, None, None], final, 1e3))
    d = np.hypot(*(final[:, 0, :2] - reference[:, 0, :2]).T)[finite]
    return {
        "non_finite": int((~finite).sum()),
        "target_end_diff_m": {"median": float(np.median(d)), "p90": float(np.quantile(d, 0.9))} if len(d) else None,
        "same_choice": bool(np.argmin(s_ref) == np.argmin(s)),
        "choice_gap_m": float(s_ref[np.argmin(s)] - s_ref.min()),
    }


def bench_planner(
    robot: Robot,
    map_path: str,
    counts: list[int],
    repeats: int = 3,
    sim_name: str = "cpu",
    scenario_number: int = 3,
    seed: int = 0,
) -> dict:
    if not Path(map_path).exists():
        raise ConfigError(f"no map at {map_path}; build one with lmjx build-map --failure case2 --out {map_path}")
    mf, sc, scene, objects, tp, acts = candidate_actions(robot, map_path, scenario_number, max(counts), seed)
    q0 = tp.park
    out: dict = {
        "scenario": scenario_number,
        "failure": mf.failure.spec,
        "counts": counts,
        "distinct_edges": len({a.edge for a in acts}),
        "action_seconds_mean": float(np.mean([a.duration for a in acts])),
        "rows": [],
    }

    def timed(sim, n: int, reps: int) -> tuple[float, np.ndarray, int]:
        times, final = [], None
        for _ in range(reps):
            sim.steps_run = 0
            t0 = time.perf_counter()
            final = sim.simulate(q0, objects, acts[:n])
            times.append(time.perf_counter() - t0)
        return statistics.median(times), final, sim.steps_run

    cpu = CpuSimulator(scene)
    cpu.simulate(q0, objects, acts[:1])  # data buffers made
    reference = {}
    for n in counts:
        reps = repeats if n <= LONG_REFERENCE else 1
        t, reference[n], steps = timed(cpu, n, reps)
        row = {"simulator": "cpu", "what": f"{cpu.description} ({usable_cores()} cores)", "candidates": n}
        out["rows"].append({**row, "seconds": t, "repeats": reps, "steps": steps, "steps_per_s": steps / t})
    near = CpuSimulator(scene, k_objects=4, robot=robot)
    n = counts[0]
    near.simulate(q0, objects, acts[:1])
    t, final, steps = timed(near, n, repeats)
    row = {"simulator": "cpu-near", "what": near.description, "candidates": n, "seconds": t, "repeats": repeats}
    out["rows"].append({**row, "steps": steps, "steps_per_s": steps / t, **agreement(sc, robot, final, reference[n])})
    if sim_name == "gpu":
        gpu = make_simulator(robot, resolve_task(scenario_number, robot, "hard"), "gpu")
        for n in counts:
            capture = gpu.prepare(n, max(len(a.q) for a in acts[:n]))
            t0 = time.perf_counter()
            gpu.simulate(q0, objects, acts[:n])  # loads the captured graphs onto the device
            first = time.perf_counter() - t0
            t, final, steps = timed(gpu, n, repeats)
            row = {"simulator": "gpu", "what": gpu.description, "candidates": n, "seconds": t, "repeats": repeats}
            row |= {"capture_s": capture, "first_call_s": first, "steps": steps, "steps_per_s": steps / t}
            row["speedup_vs_cpu"] = _row(out, "cpu", n)["seconds"] / t
            out["rows"].append({**row, **agreement(sc, robot, final, reference[n])})
        out["gpu_model_s"] = gpu.capture_seconds - sum(r.get("capture_s", 0) for r in out["rows"])
        decision_sim = gpu
    else:
        decision_sim = cpu
    # one whole Greedy decision with the simulator's default candidate count
    cfg = PlannerConfig(asm="greedy", greedy_candidates=DEFAULT_CANDIDATES[decision_sim.name])
    planner = Planner(robot, mf.failure, mf.reach, mf.edges, sc, decision_sim, cfg)
    obs = Observation(q0, objects, 0.0)
    planner.choose(obs, np.random.default_rng(seed))  # transit kernel compiled, graphs loaded
    times, sim_seconds = [], []
    for r in range(repeats):
        _, rec = planner.choose(obs, np.random.default_rng(seed + 1 + r))
        times.append(rec.planning_s)
        sim_seconds.append(rec.simulation_s)  # every simulation of the decision, rescoring's included
    out["decision"] = {
        "simulator": decision_sim.name,
        "candidates": cfg.greedy_candidates,
        "rescored": cfg.rescore_top,  # its best simulated again from cfg.rescore_draws - 1 more starts
        "simulated": rec.simulated,
        "seconds": statistics.median(times),
        "simulation_seconds": statistics.median(sim_seconds),
    }
    return out


def _row(report: dict, simulator: str, n: int) -> dict:
    return next(r for r in report["rows"] if r["simulator"] == simulator and r["candidates"] == n)
