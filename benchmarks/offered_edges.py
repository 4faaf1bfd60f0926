"""What the edges the planner offers "over the target" do: each executed once from a trial's
start in the "real" world (C MuJoCo), how far it moves the target, and what its transit
touches.

For each map, scenario and seed (seeds of their own, not the evaluation's), the planner's
`decide` machinery offers its edges over the target at the trial's start; up to `--per`
of them, in the random order Random would draw them, are turned into actions (the
planner's transits) and executed, each in a fresh "real" world of that seed.  Prints and
writes (JSON) the share that moves the target by 1 cm or more, the median displacement,
and the share whose transit touches a movable object or a fixed obstacle.

    python benchmarks/offered_edges.py maps/case1.h5 maps/case2.h5 --out offered.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from lmjx.mapfile.read import load_map
from lmjx.model.robot import load_robot
from lmjx.planner.edge_planner import edges_over_target
from lmjx.planner.transit import TransitPlanner
from lmjx.sim.realworld import SimulatedRealWorld
from lmjx.sim.scenarios import sample_layout, scenario


def measure(map_path: str, scenarios: list[int], seeds: list[int], per: int, robot_name: str) -> dict:
    robot = load_robot(robot_name)
    m = load_map(map_path, robot=robot)
    transits = TransitPlanner(robot, m.failure, batched=True)
    moved, touched, fixed, offered = [], 0, 0, []
    for s in scenarios:
        sc = scenario(s, robot.profile.task_scale, "hard")
        for seed in seeds:
            layout = sample_layout(sc, seed)
            world = SimulatedRealWorld(robot, seed)
            obs = world.reset(layout, transits.park)
            if hasattr(transits, "set_scene"):
                transits.set_scene(sc, obs.objects)
            edges = edges_over_target(m.edges, m.reach, obs.objects[0, :2], float(sc.target.half[0]), 0.01)
            offered.append(len(edges))
            order = np.random.default_rng(seed).permutation(edges)
            for a in transits.actions(m.edges, order, obs.robot_q, per):
                w = SimulatedRealWorld(robot, seed)
                before = w.reset(layout, transits.park)
                t0 = w.truth()[0, :2].copy()
                # start where the planner's observation put the arm
                after = w.execute(a)
                moved.append(float(np.hypot(*(w.truth()[0, :2] - t0))))
                touched += bool(getattr(after, "transit_contacts", ()))
                fixed += bool(getattr(after, "transit_hit_fixed", False))
                del before
    n = len(moved)
    return {
        "map": map_path,
        "scenarios": scenarios,
        "seeds": seeds,
        "offered_median": float(np.median(offered)) if offered else 0.0,
        "actions": n,
        "moved_1cm_share": float(np.mean(np.asarray(moved) >= 0.01)) if n else None,
        "moved_median_m": float(np.median(moved)) if n else None,
        "transit_touched_object_share": touched / n if n else None,
        "transit_hit_fixed_share": fixed / n if n else None,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("maps", nargs="+")
    ap.add_argument("--robot", default="panda")
    ap.add_argument("--scenarios", default="1,2,3")
    ap.add_argument("--seeds", default="900-904", help="trial seeds, a range a-b or a list (not the evaluation's)")
    ap.add_argument("--per", type=int, default=20, help="offered edges executed per trial start")
    ap.add_argument("--out")
    args = ap.parse_args()
    if "-" in args.seeds:
        a, b = (int(x) for x in args.seeds.split("-"))
        seeds = list(range(a, b + 1))
    else:
        seeds = [int(x) for x in args.seeds.split(",")]
    scenarios = [int(x) for x in args.scenarios.split(",")]
    rows = []
    for path in args.maps:
        t0 = time.perf_counter()
        row = measure(path, scenarios, seeds, args.per, args.robot)
        row["seconds"] = round(time.perf_counter() - t0, 1)
        print(json.dumps(row))
        rows.append(row)
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
