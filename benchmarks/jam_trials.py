"""Trials that got stuck, run again: does the planner now find a transit where it found none?

    python benchmarks/jam_trials.py FAILURE:SCENARIO:SEED:N:TASKS ...   (maps in /tmp/ev or $LMJX_MAPS)

Each argument names a Random trial of an evaluation that ended "no feasible transit" after N
actions; it is run again with today's code for at most N + 3 actions (Random simulates
nothing, so the trial is the evaluation's up to float32 ties) and one JSON line printed: how
it ended, its actions, and how many of their transits touched a movable object or a fixed
obstacle in the "real" world."""

import json
import os
import sys

from lmjx.evaluation.trial import run_trial, setup_trial
from lmjx.mapfile.read import load_map
from lmjx.model.robot import load_robot
from lmjx.sim.scenarios import resolve_task
from lmjx.types import PlannerConfig

folder = os.environ.get("LMJX_MAPS", "/tmp/ev")
robot = load_robot("panda")
maps = {f: load_map(f"{folder}/{f}.h5") for f in ("case1", "case2")}
for spec in sys.argv[1:]:
    f, sc, seed, n, tasks = spec.split(":")
    cfg = PlannerConfig(asm="random", max_actions=int(n) + 3)
    r = run_trial(setup_trial(robot, maps[f], resolve_task(int(sc), robot, tasks), cfg, seed=int(seed)))
    steps = [s for s in r.steps if s.edge >= 0]
    print(json.dumps({"trial": spec, "end": r.reason, "actions": r.actions,
                      "contacts": sum(bool(s.transit_contacts) for s in steps),
                      "fixed": sum(bool(s.transit_hit_fixed) for s in steps)}), flush=True)  # fmt: skip
