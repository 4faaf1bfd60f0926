"""Compute a map's push counts (`lmjx.planner.pushfield`, what `--push-weight` weighs the score by)
for the scenarios of a task set, once, into lmjx's cache folder.

Greedy and Lazy with a push weight (1 by default) need the counts of their
map and scenario; each process computes them on first use and keeps them in the cache folder
(`lmjx.planner.pushfield.cached_counts`).  An evaluation started as dozens of processes at once would
compute them dozens of times side by side; run this first and they all find them there.
Run it on the platform the evaluation runs on (the counts' key holds JAX's platform):

    python benchmarks/warm_push_counts.py --map maps/case2.h5 --tasks hard --scenarios 1,2,3
"""

from __future__ import annotations

import argparse
import sys
import time

from lmjx.errors import LmjxError
from lmjx.mapfile.read import load_map
from lmjx.planner.scoring import _score_field
from lmjx.sim.scenarios import TASK_SETS, scenario
from lmjx.types import PlannerConfig


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--map", required=True, help="a map file from lmjx build-map")
    p.add_argument("--tasks", default="paper", choices=TASK_SETS, help="the task set (default paper)")
    p.add_argument("--scenarios", default="1,2,3", help="comma-separated scenario numbers (default 1,2,3)")
    p.add_argument("--push-weight", type=float, default=PlannerConfig().push_weight, help="the weight (default 1)")
    args = p.parse_args(argv)
    try:
        numbers = [int(s) for s in args.scenarios.split(",")]
    except ValueError as e:
        print(f"warm_push_counts: bad --scenarios {args.scenarios!r}: {e}", file=sys.stderr)
        return 2
    try:
        m = load_map(args.map)
        if m.edges is None:
            raise LmjxError(f"{args.map} has no edges")
        robot = m.robot
        assert robot is not None
        cfg = PlannerConfig(asm="greedy", push_weight=args.push_weight)
        cfg.validate()
        for s in numbers:
            sc = scenario(s, robot.profile.task_scale, args.tasks)
            t0 = time.perf_counter()
            _score_field(robot, m.failure, m.reach, m.edges, sc, cfg)
            print(f"{args.map}: scenario {s} ({args.tasks} tasks): push counts in {time.perf_counter() - t0:.1f} s")
    except LmjxError as e:
        print(f"warm_push_counts: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
