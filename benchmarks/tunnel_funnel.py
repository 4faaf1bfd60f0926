"""Why a trial ends with "no feasible transit": at the decision where the planner finds no
action, count the edges over the target whose start is clear, those that also act on it
while keeping FIXED_MARGIN from the fixed obstacles, and the actions (with a transit) found,
for FIXED_MARGIN 2, 1.5, 1 and 0.5 cm (issue 19's case-1 tunnel diagnosis, docs/EVALUATION.md).

    python benchmarks/tunnel_funnel.py MAPS_DIR case1:2:2000:random:paper [...]

Each argument: FAILURE:SCENARIO:TRIAL_SEED:ASM:TASKS; the map is MAPS_DIR/FAILURE.h5.
Prints one line per margin at every such decision, then the trial's outcome as JSON."""

from __future__ import annotations

import json
import sys

import numpy as np

from lmjx.evaluation.trial import run_trial, setup_trial
from lmjx.mapfile.read import load_map
from lmjx.model.robot import load_robot
from lmjx.planner import transit as acts
from lmjx.sim.scenarios import resolve_task
from lmjx.types import PlannerConfig

_orig = acts.TransitPlanner.actions


def _actions(self, bundle, edges, q_now, want, came_from=None, trail=None):
    out = _orig(self, bundle, edges, q_now, want, came_from, trail)
    if not out and len(edges):
        edges = np.asarray(edges)
        keep = acts.FIXED_MARGIN
        try:
            for fm in (0.02, 0.015, 0.01, 0.005):
                acts.FIXED_MARGIN = fm
                clear = edges[~self.blocked(bundle.q_start[edges].astype(np.float64))]
                acting = self.edges_usable(bundle, clear)
                got = _orig(self, bundle, edges, q_now, 5, came_from, trail)
                print(
                    f"  margin {fm * 100:.1f} cm: {len(edges)} over the target, {len(clear)} start clear, "
                    f"{int(acting.sum())} acting, {len(got)} with a transit {[a.route for a in got]}",
                    flush=True,
                )
        finally:
            acts.FIXED_MARGIN = keep
    return out


def main() -> None:
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    acts.TransitPlanner.actions = _actions
    robot = load_robot("panda")
    maps: dict = {}
    for spec in sys.argv[2:]:
        f, sc, seed, asm, tasks = spec.split(":")
        maps.setdefault(f, load_map(f"{sys.argv[1]}/{f}.h5"))
        task = resolve_task(int(sc), robot, tasks)
        r = run_trial(setup_trial(robot, maps[f], task, PlannerConfig(asm=asm), seed=int(seed)))
        steps = [s for s in r.steps if s.edge >= 0]
        print(
            json.dumps(
                {
                    "trial": spec,
                    "success": r.success,
                    "end": r.reason,
                    "actions": r.actions,
                    "routes": [s.transit_route for s in steps],
                }
            ),
            flush=True,
        )


if __name__ == "__main__":
    main()
