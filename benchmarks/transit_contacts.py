"""Which transits touch a movable object in the "real" world, and where they began: for each
executed action of some trials, its route, the objects it touched (`transit_contacts`), and
the planned slack to every object at the transit's start and along it (issue 19's 2 %
criterion; docs/EVALUATION.md).  Variants of the transit rules as options, to compare.

    python benchmarks/transit_contacts.py MAPS_DIR OUT.jsonl [--leave-tolerance M]
        [--near-speed F] case1:1:1001:random:hard [...]

Each trial: FAILURE:SCENARIO:TRIAL_SEED:ASM:TASKS; the map is MAPS_DIR/FAILURE.h5 (Random and
Lazy-free settings need no planner simulator: use random)."""

from __future__ import annotations

import argparse
import json

import numpy as np

from lmjx.evaluation.trial import setup_trial
from lmjx.mapfile.read import load_map
from lmjx.model.robot import load_robot
from lmjx.planner import transit as acts
from lmjx.sim.scenarios import resolve_task
from lmjx.types import PlannerConfig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("maps")
    ap.add_argument("out")
    ap.add_argument("trials", nargs="+")
    ap.add_argument("--leave-tolerance", type=float, help=f"LEAVE_TOLERANCE [m] (default {acts.LEAVE_TOLERANCE})")
    ap.add_argument("--near-speed", type=float, help=f"NEAR_SPEED (default {acts.NEAR_SPEED})")
    args = ap.parse_args()
    if args.leave_tolerance is not None:
        acts.LEAVE_TOLERANCE = args.leave_tolerance
    if args.near_speed is not None:
        acts.NEAR_SPEED = args.near_speed
    robot = load_robot("panda")
    maps: dict = {}
    with open(args.out, "a") as out:
        for spec in args.trials:
            f, sc, seed, asm, tasks = spec.split(":")
            maps.setdefault(f, load_map(f"{args.maps}/{f}.h5"))
            task = resolve_task(int(sc), robot, tasks)
            st = setup_trial(robot, maps[f], task, PlannerConfig(asm=asm), seed=int(seed))
            planner, world = st.planner, st.world
            execute = world.execute

            def traced(action, planner=planner, execute=execute, spec=spec):
                tr = action.q[: action.transit_steps]
                names = list(planner.transits.scene.names)
                slk = planner.transits.scene_slacks(tr) if len(tr) else np.zeros((0, len(names)))
                obs = execute(action)
                rec = {
                    "trial": spec,
                    "route": action.route,
                    "contacts": list(obs.transit_contacts),
                    "left": list(obs.transit_left),
                    "start_slack": {n: round(float(slk[0, i]), 5) for i, n in enumerate(names)} if len(tr) else {},
                    "min_slack": {n: round(float(slk[:, i].min()), 5) for i, n in enumerate(names)} if len(tr) else {},
                }
                out.write(json.dumps(rec) + "\n")
                out.flush()
                return obs

            world.execute = traced
            r = planner.run(world, st.layout, st.planner_seed)
            print(json.dumps({"trial": spec, "success": r.success, "end": r.reason, "actions": r.actions}), flush=True)


if __name__ == "__main__":
    main()
