"""`lmjx bench` planner section: whole decisions of each ASM, timed as a user's `lmjx plan`
makes them, with where their time goes.

For each map (a failure), scenario of the task set and ASM, `trials` closed-loop trials on
seeds of their own (`SEED_BASE`: a base no evaluation uses), one trial at a time, the
planner's simulator shared by a scenario's trials (its programs built once, as in a long
run).  Each decision's `latency_s` (the wall time from the observation to the chosen
action, compiling excluded) and `phase_s` (offer, transit, simulate, rescore; execute and
compile apart: `lmjx.planner.phases`) come from the planner's own records.  Per cell: the
decisions' median, 90th percentile and largest latency, and each phase's median.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np

from lmjx.evaluation.evaluate import trial_seed
from lmjx.mapfile.read import MapFile
from lmjx.model.robot import Robot
from lmjx.planner.levers import planner_config
from lmjx.planner.phases import PHASES
from lmjx.planner.trial import make_simulator, run_trial, setup_trial
from lmjx.sim.scenarios import resolve_task
from lmjx.types import ASMS

SEED_BASE = 52  # trial seeds 5,2xx,xxx: no evaluation's (the evaluation's are base 0; its replicate registers its own)


def bench_decisions(
    robot: Robot,
    maps: dict[str, MapFile],
    sim_name: str,
    trials: int = 3,
    scenarios: tuple[int, ...] = (1, 2, 3),
    asms: tuple[str, ...] = ASMS,
    tasks: str = "paper",
    max_actions: int | None = None,
    seed_base: int = SEED_BASE,
    say: Callable[[str], None] | None = None,
) -> dict:
    """Decisions timed per (failure, scenario, ASM) cell; see the module docstring."""
    rows = []
    for s in scenarios:
        task = resolve_task(s, robot, tasks)
        sim = None  # made on the first ASM that simulates, shared by the scenario's trials
        for f, m in maps.items():
            for asm in asms:
                cfg = planner_config(asm, sim_name, {"max_actions": max_actions} if max_actions else {})
                if asm != "random" and sim is None:
                    sim = make_simulator(robot, task, sim_name, servo=cfg.servo)
                latencies, phases, ends = [], [], []
                t0 = time.perf_counter()
                for t in range(trials):
                    seed = trial_seed(seed_base, s, t)
                    setup = setup_trial(robot, m, task, cfg, seed, sim if asm != "random" else None)
                    res = run_trial(setup)
                    ends.append(res.reason)
                    for step in res.steps:
                        latencies.append(step.latency_s)
                        phases.append(step.phase_s)
                row = {
                    "failure": f,
                    "scenario": s,
                    "asm": asm,
                    "trials": trials,
                    "decisions": len(latencies),
                    "latency_s": _spread(latencies),
                    "phase_s": {k: round(statistics.median([p.get(k, 0.0) for p in phases]), 4) for k in PHASES}
                    if phases
                    else {},
                    "ends": {e: ends.count(e) for e in sorted(set(ends))},
                    "candidates": cfg.greedy_candidates if asm == "greedy" else cfg.lazy_tries if asm == "lazy" else 1,
                    "wall_s": round(time.perf_counter() - t0, 2),
                }
                rows.append(row)
                if say is not None:
                    lat = row["latency_s"]
                    say(f"decisions {f} scenario {s} {asm}: {row['decisions']} decisions, median "
                        f"{lat.get('median', float('nan')):.2f} s")  # fmt: skip
    return {
        "simulator": sim_name,
        "tasks": tasks,
        "seed_base": seed_base,
        "trials_per_cell": trials,
        "maps": {f: {"path": str(m.path), "edges": m.edges.n_edges if m.edges else 0} for f, m in maps.items()},
        "rows": rows,
    }


def _spread(xs: list[float]) -> dict:
    if not xs:
        return {}
    a = np.asarray(xs)
    return {"median": round(float(np.median(a)), 4), "p90": round(float(np.quantile(a, 0.9)), 4),
            "max": round(float(a.max()), 4)}  # fmt: skip


def print_decisions(report: dict) -> None:
    """The section as a table: per cell, the decisions' latency and the median of each phase."""
    head = f"{report['simulator']} simulator, {report['tasks']} tasks, {report['trials_per_cell']} trials a cell"
    print(f"  decisions ({head}, seeds of base {report['seed_base']}): latency [s] median / p90 / max; phases' medians")
    for r in report["rows"]:
        lat = r["latency_s"]
        if not lat:
            print(f"    {r['failure']} s{r['scenario']} {r['asm']:>6}: no decision")
            continue
        ph = ", ".join(f"{k} {v:.2f}" for k, v in r["phase_s"].items() if k not in ("execute", "compile"))
        print(f"    {r['failure']} s{r['scenario']} {r['asm']:>6}: {r['decisions']:3d} decisions, "
              f"{lat['median']:.2f} / {lat['p90']:.2f} / {lat['max']:.2f} s ({ph})")  # fmt: skip
