"""Can the arm reach behind the target in case 2's tunnel while keeping its margins?  A
question for the map, not the planner: the hard set's failing tunnel trials end with the
target beyond the opening's edge, where no edge of the map acts on it from a clear state
(docs/EVALUATION.md, "The sixth session").

Uniform samples of the free joints (the locked ones at the failure's angles); for each, the
arm's clearance (lmjx's box-clearance kernel, its collision capsules) to a box just behind
the target (the side away from the goal: 3 cm deep, as wide as the target, 6 cm high), to
the target, to the tunnel's wall and roof, and to the table and itself.  Counts, per target
position, the samples with a capsule inside the box behind, then those also FIXED_MARGIN
from the wall and roof, then those also OBJECT_MARGIN from the target (where a push toward
the goal could start).

    python benchmarks/tunnel_behind.py [--samples 3000000] [--targets 0.47,0.40 0.621,0.347] [--failure case2]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from lmjx.errors import LmjxError
from lmjx.model.failure import parse_failure
from lmjx.model.robot import load_robot
from lmjx.planner.clearance import FIXED_MARGIN, OBJECT_MARGIN, SceneBoxes, box_kernel, scene_boxes
from lmjx.planner.transit import TransitPlanner
from lmjx.sim.scenarios import scenario

BEHIND = (0.025, 0.015, 0.03)  # [m] the box behind the target: half sizes (x, y, z)


def position(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"a target position is x,y in metres, not {text!r}") from None
    return x, y


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=int, default=3_000_000, help="configurations sampled (default 3,000,000)")
    ap.add_argument("--targets", type=position, nargs="+", default=[(0.47, 0.40), (0.621, 0.347)],
                    help="target centres x,y [m] (default: the hard tunnel's start; its failures' end)")  # fmt: skip
    ap.add_argument("--failure", default="case2", help="the locked joints (default case2)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if args.samples < 1:
        sys.exit("tunnel_behind: --samples must be positive")
    robot = load_robot("panda")
    try:
        failure = parse_failure(args.failure, robot)
    except LmjxError as e:
        sys.exit(f"tunnel_behind: {e}")
    sc = scenario(2, robot.profile.task_scale, "hard")
    tp = TransitPlanner(robot, failure, batched=True)
    rng = np.random.default_rng(args.seed)
    q = np.tile(tp.park, (args.samples, 1))
    for j in (j for j in range(robot.nq) if j not in failure.locked):
        q[:, j] = rng.uniform(robot.lower[j], robot.upper[j], args.samples)
    t0 = time.perf_counter()
    q = q[~tp.colliding_batch(q)].astype(np.float32)
    took = time.perf_counter() - t0
    print(f"{args.samples:,} samples, {len(q):,} clear of the table and the arm itself ({took:.0f} s)")
    away = 1.0 if sc.goal_center[1] < sc.target.y else -1.0  # behind: the side away from the goal, in y
    for tx, ty in args.targets:
        boxes = scene_boxes(sc, np.array([[tx, ty, sc.target.half[2], 1.0, 0.0, 0.0, 0.0]]))
        behind = np.array([tx, ty + away * (sc.target.half[1] + BEHIND[1]), BEHIND[2]])
        scene = SceneBoxes((*boxes.names, "behind"), np.append(boxes.movable, True),
                           np.vstack([boxes.centers, behind]), np.concatenate([boxes.rots, np.eye(3)[None]]),
                           np.vstack([boxes.halves, BEHIND]))  # fmt: skip
        c = box_kernel(robot, scene.padded(8)).run(q)["box_clearance"][:, : len(scene.names)]
        fixed = c[:, ~scene.movable].min(axis=1) >= FIXED_MARGIN
        inside = c[:, -1] < 0
        start = inside & fixed & (c[:, 0] >= OBJECT_MARGIN)
        print(
            f"target at ({tx:g}, {ty:g}): a capsule behind it {inside.sum():,}; of those {FIXED_MARGIN * 100:g} cm "
            f"from the wall and roof {(inside & fixed).sum():,}; and {OBJECT_MARGIN * 100:g} cm from the target "
            f"{start.sum():,}"
        )


if __name__ == "__main__":
    main()
