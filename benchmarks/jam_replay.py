"""A trial that ended "no feasible transit" after its first push, replayed: is the arm jammed,
and which actions does the next decision find?  (issue 19; docs/EVALUATION.md, "A jammed arm
escapes")

    python benchmarks/jam_replay.py MAPS_DIR FAILURE SCENARIO SEED EDGE [--tasks hard] [--want 16] [--no-escape]

Sets up trial SEED of SCENARIO exactly as `lmjx evaluate` does (its layout and its perturbed
"real" world), executes EDGE (the trial's first action, from its results.json record) from the
park pose in that world, then, with the objects where they were observed after it, asks the
transit planner for the first WANT actions among the edges over the target in a seeded random
order, as the next decision would.  Prints one JSON line: the target's displacement, the
arm's slack to each box's margin, whether the way back (`retreat`) exists, the `escape`'s
length, and the actions found with their routes (`--no-escape`: as before the escape
existed)."""

from __future__ import annotations

import argparse
import collections
import json
import time

import numpy as np

from lmjx.evaluation.trial import setup_trial
from lmjx.mapfile.read import load_map
from lmjx.model.robot import load_robot
from lmjx.planner.edge_planner import edges_over_target
from lmjx.planner.transit import TransitPlanner
from lmjx.sim.scenarios import resolve_task
from lmjx.types import PlannerConfig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("maps")
    ap.add_argument("failure")
    ap.add_argument("scenario", type=int)
    ap.add_argument("seed", type=int)
    ap.add_argument("edge", type=int)
    ap.add_argument("--tasks", default="hard")
    ap.add_argument("--want", type=int, default=16)
    ap.add_argument("--no-escape", action="store_true")
    args = ap.parse_args()
    if args.no_escape:
        TransitPlanner.escape = lambda self, q_now: None
    robot = load_robot("panda")
    m = load_map(f"{args.maps}/{args.failure}.h5")
    task = resolve_task(args.scenario, robot, args.tasks)
    st = setup_trial(robot, m, task, PlannerConfig(asm="random"), seed=args.seed)
    p, tp = st.planner, st.planner.transits
    obs = st.world.reset(st.layout, tp.park)
    trail = obs.robot_q[None].copy()
    tp.set_scene(p.sc, obs.objects)
    first = tp.actions(p.bundle, np.array([args.edge]), obs.robot_q, 1, None, trail)
    assert first, "that edge has no transit from the park pose here"
    obs = st.world.execute(first[0])
    came = first[0].q[first[0].transit_steps :].astype(p.bundle.q_start.dtype)
    trail = np.concatenate([trail, first[0].q])
    tp.set_scene(p.sc, obs.objects)
    q = obs.robot_q
    edges = edges_over_target(p.bundle, p.reach, obs.objects[0, :2], float(p.sc.target.half[0]), p.config.target_margin)
    esc = tp.escape(q)
    slack = tp.scene_slacks(q[None])[0]
    t0 = time.perf_counter()
    acts = tp.actions(p.bundle, np.random.default_rng(0).permutation(edges), q, args.want, came, trail)
    line = {
        "failure": args.failure, "scenario": args.scenario, "seed": args.seed, "edge": args.edge,
        "target_moved_m": round(float(obs.target_moved_m), 4),
        "slack_mm": {n: round(1000 * float(v), 1) for n, v in zip(tp.scene.names, slack, strict=True)},
        "retreat": tp.retreat(q, came) is not None,
        "escape_steps": None if esc is None else len(esc),
        "edges_over_target": len(edges),
        "actions": len(acts), "routes": dict(collections.Counter(a.route for a in acts)),
        "search_s": round(time.perf_counter() - t0, 1), "escape_on": not args.no_escape,
    }  # fmt: skip
    print(json.dumps(line), flush=True)


if __name__ == "__main__":
    main()
