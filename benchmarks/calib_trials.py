"""Trials on calibration seeds (never the evaluation's), one JSON line each: how a planner
change does before it meets the evaluation (issue 19's tunnel, docs/EVALUATION.md).

    python benchmarks/calib_trials.py MAPS_DIR FAILURE SCENARIO ASM FIRST COUNT [--tasks paper]
        [--no-trail] [--candidates 32] [--max-actions N]

Runs trials seeded `trial_seed(7, SCENARIO, FIRST + i)` for i < COUNT (7xx,xxx: the
calibration base, see benchmarks/calibrate_tasks.py) on C MuJoCo; Greedy and Lazy simulate
on C MuJoCo with `--candidates`; `--max-actions`: another budget than the task set's (the
runs of 2026-11-25 in calib_tunnel_greedy_cpu_2026-11-25.jsonl had 10, the paper set's budget
then).  `--no-trail`: transits without the way back
(`TransitPlanner.trail_back` returns nothing), to compare."""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from calibrate_tasks import CAL_BASE  # (this folder: the script's own)

from lmjx.evaluation.evaluate import trial_seed
from lmjx.evaluation.trial import run_trial, setup_trial
from lmjx.mapfile.read import load_map
from lmjx.model.robot import load_robot
from lmjx.planner.transit import TransitPlanner
from lmjx.sim.scenarios import resolve_task
from lmjx.types import PlannerConfig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("maps")
    ap.add_argument("failure")
    ap.add_argument("scenario", type=int)
    ap.add_argument("asm", choices=("random", "lazy", "greedy"))
    ap.add_argument("first", type=int)
    ap.add_argument("count", type=int)
    ap.add_argument("--tasks", default="paper")
    ap.add_argument("--no-trail", action="store_true")
    ap.add_argument("--candidates", type=int, default=32)
    ap.add_argument("--max-actions", type=int, default=None)
    args = ap.parse_args()
    if args.no_trail:
        TransitPlanner.trail_back = lambda self, source, trail: np.zeros((0, len(source)))
    robot = load_robot("panda")
    m = load_map(f"{args.maps}/{args.failure}.h5")
    transits = TransitPlanner(robot, m.failure)
    for t in range(args.first, args.first + args.count):
        seed = trial_seed(CAL_BASE, args.scenario, t)
        cfg = PlannerConfig(asm=args.asm, greedy_candidates=args.candidates, max_actions=args.max_actions)
        t0 = time.perf_counter()
        task = resolve_task(args.scenario, robot, args.tasks)
        r = run_trial(setup_trial(robot, m, task, cfg, seed=seed, transits=transits))
        steps = [s for s in r.steps if s.edge >= 0]
        line = {
            "seed": seed,
            "success": r.success,
            "end": r.reason,
            "actions": r.actions,
            "routes": [s.transit_route for s in steps],
            "distance_cm": [round(100 * s.distance_after, 1) for s in steps],
            "candidates": [s.simulated for s in steps],
            "contacts": sum(bool(s.transit_contacts) for s in steps),
            "fixed": sum(bool(s.transit_hit_fixed) for s in steps),
            "wall_s": round(time.perf_counter() - t0, 1),
        }
        print(json.dumps(line), flush=True)


if __name__ == "__main__":
    main()
