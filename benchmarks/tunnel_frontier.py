"""How far one action can push the target through the paper set's tunnel (scenario 2), from
a row of places along the way: is the goal within the locked arm's reach?  (Issue 19: case
1's Greedy stalls 10-13 cm from the goal's centre, docs/EVALUATION.md.)

    python benchmarks/tunnel_frontier.py MAP [--ys 0.18,0.20,...] [--most 512]

For each y, the target (no noise) at (x of its start, y): the edges over the target, those
the planner would offer (clear start, acting while keeping FIXED_MARGIN from the wall and
the roof), and of these at most --most (a seeded sample), each executed from its own start
(the arm placed there: what the edges can do, whatever the transits reach) and simulated
with C MuJoCo on the planner's scene; prints how many move the target 1 cm or more toward
the goal (+y), and the farthest y the target's centre reaches.  The goal
square's near edge and where the planner stops (goal_margin inside) are printed first."""

from __future__ import annotations

import argparse
import json

import numpy as np

from lmjx.mapfile.read import load_map
from lmjx.model.robot import load_robot
from lmjx.planner.edge_planner import edges_over_target
from lmjx.planner.transit import TransitPlanner
from lmjx.sim.cpu import CpuSimulator
from lmjx.sim.scenarios import scenario
from lmjx.sim.scene import build_scene, object_qpos
from lmjx.types import PlannerConfig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("map")
    ap.add_argument("--ys", default="0.18,0.20,0.22,0.24,0.25,0.26,0.27,0.28")
    ap.add_argument("--most", type=int, default=512)
    args = ap.parse_args()
    robot = load_robot("panda")
    m = load_map(args.map)
    sc = scenario(2, robot.profile.task_scale, "paper")
    cfg = PlannerConfig()
    near = sc.goal_center[1] - sc.goal_half[1]
    print(json.dumps({"failure": m.failure.spec, "goal_near_edge_y": round(near, 3),
                      "planner_stops_at_y": round(near + cfg.goal_margin, 3)}))  # fmt: skip
    transits = TransitPlanner(robot, m.failure)
    scene = build_scene(robot, sc)
    sim = CpuSimulator(scene)
    x0 = sc.target.x
    rng = np.random.default_rng(0)
    for y in (float(v) for v in args.ys.split(",")):
        objects = object_qpos(scene, np.array([[x0, y, 0.0]]))
        transits.set_scene(sc, objects)
        edges = edges_over_target(m.edges, m.reach, np.array([x0, y]), float(sc.target.half[0]), cfg.target_margin)
        clear = edges[~transits.blocked(m.edges.q_start[edges].astype(np.float64))]
        acting = clear[transits.edges_usable(m.edges, clear)]
        pick = rng.permutation(acting)[: args.most]
        # each edge from its own start: the arm placed there (no transit), the edge as offered
        q0s = m.edges.q_start[pick].astype(np.float64)
        acts = [a for e, q0 in zip(pick, q0s, strict=True) for a in transits.actions(m.edges, np.array([e]), q0, 1)]
        row = {"y": y, "over": len(edges), "start_clear": len(clear), "acting": len(acting), "simulated": len(acts)}
        if acts:
            ty = np.array([o[0, 0, 1] for o in sim.simulate_many([(a.q[0], objects, [a]) for a in acts])])
            row |= {"moved_1cm_plus_y": int(np.sum(ty - y >= 0.01)), "farthest_y": round(float(ty.max()), 4),
                    "top5_y": [round(float(v), 4) for v in np.sort(ty)[-5:][::-1]]}  # fmt: skip
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
