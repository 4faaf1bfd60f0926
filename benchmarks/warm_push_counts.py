"""Make sure a map's push counts (`lmjx.mapfile.pushmap`, what `--push-weight` weighs the
score by) are at hand for the scenarios of a task set, and say where each came from.

A map built by this lmjx stores the counts of its robot's built-in scenarios, both task sets
(`/edges/push`, maps/README.md), computed on the platform it was built on: on that platform
the planner reads them and this tool reports "stored in the map".  A map of schema version 2,
or one used on another platform (its counts' key holds JAX's platform: a map built on a GPU,
planned with JAX_PLATFORMS=cpu), has them computed on first use and kept in lmjx's cache
folder (`lmjx.mapfile.pushmap.cached_counts`); an evaluation started as dozens of processes
at once would compute them side by side, so run this first, on the platform the evaluation
runs on, and they all find them there ("computed", then "read from the cache folder"):

    python benchmarks/warm_push_counts.py --map maps/case2.h5 --tasks hard --scenarios 1,2,3

`--compute` times the computation itself whatever the map and the cache hold (what a map
without stored counts costs on first use): the map's samples (once, with the first scenario)
apart from each scenario's pass, and whether the result equals the counts the map stores.
"""

from __future__ import annotations

import argparse
import sys
import time

from lmjx.errors import LmjxError
from lmjx.runtime.cache import configure
from lmjx.sim.scenarios import TASK_SETS, scenario

SOURCES = {
    "map": "stored in the map",
    "cache": "read from the cache folder",
    "computed": "computed (kept in the cache folder)",
}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--map", required=True, help="a map file from lmjx build-map")
    p.add_argument("--tasks", default="paper", choices=TASK_SETS, help="the task set (default paper)")
    p.add_argument("--scenarios", default="1,2,3", help="comma-separated scenario numbers (default 1,2,3)")
    p.add_argument("--compute", action="store_true", help="compute and time them (the map's, the cache's aside)")
    args = p.parse_args(argv)
    try:
        numbers = [int(s) for s in args.scenarios.split(",")]
    except ValueError as e:
        print(f"warm_push_counts: bad --scenarios {args.scenarios!r}: {e}", file=sys.stderr)
        return 2
    configure()  # lmjx's cache folder, as `lmjx plan` has it (before JAX starts): compiled programs, counts
    import numpy as np

    from lmjx.mapfile.pushmap import HEIGHT, bundle_samples, counts_for, counts_key, scenario_counts, scenario_field
    from lmjx.mapfile.read import load_map
    from lmjx.runtime.batching import backend

    try:
        m = load_map(args.map)
        if m.edges is None or m.reach is None:
            raise LmjxError(f"{args.map} has no edges")
        robot = m.robot
        assert robot is not None
        if args.compute:
            t0 = time.perf_counter()
            samples = bundle_samples(robot, m.edges, m.reach, HEIGHT, progress=True)
            print(f"{args.map}: the map's push samples in {time.perf_counter() - t0:.2f} s ({len(samples):,} samples "
                  f"of {m.edges.n_edges:,} edges, {backend()}: {samples.runs} runs in {samples.device_calls} device "
                  "calls)")  # fmt: skip
        for s in numbers:
            sc = scenario(s, robot.profile.task_scale, args.tasks)
            field = scenario_field(robot, sc)
            t0 = time.perf_counter()
            if args.compute:
                counts = scenario_counts(robot, m.failure, m.edges, m.reach, sc, field)
                stored = m.edges.push.get(counts_key(robot, m.edges, m.reach, sc, field))
                said = "computed"
                if stored is not None:
                    said += ", equal to the map's" if np.array_equal(stored, counts) else ", NOT EQUAL to the map's"
            else:
                counts, source = counts_for(robot, m.failure, m.edges, m.reach, sc, field)
                said = SOURCES[source]
            print(f"{args.map}: scenario {s} ({args.tasks} tasks): push counts {said} in "
                  f"{time.perf_counter() - t0:.2f} s ({int(counts.sum()):,} (cell, edge) pairs)")  # fmt: skip
    except LmjxError as e:
        print(f"warm_push_counts: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
