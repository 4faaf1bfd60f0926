"""Why the GPU simulator and C MuJoCo part on one decision of the agreement test: the
decision's candidates simulated by both (the picks, the candidates whose target ends differ
most), then, for one candidate, the action cut after k control points (each cut held and
settled as a whole action is), to see where and how the two part.

    python benchmarks/agreement_miss.py MAPS_DIR FAILURE SCENARIO SEED DEPTH [--candidate I] [--device cpu]

MAPS_DIR: the agreement test's maps (`lmjx build-map --failure caseN --edges 100000 --seed
2026`); SEED, DEPTH: a row of the test's report (`LMJX_TEST_REPORT`, `per_decision`).  Needs
warp-lang; `--device cpu` runs MuJoCo Warp on Warp's CPU device (a machine without a GPU:
about 30 s for 64 candidates), else the first CUDA device.  Without `--candidate` the one
whose target ends differ most is cut.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from agreement_run import setup

from lmjx.evaluation.agreement import decision_states
from lmjx.evaluation.trial import make_simulator
from lmjx.planner.goalfield import GoalField
from lmjx.planner.scoring import score, table_bounds
from lmjx.sim.scenarios import resolve_task, scenario


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("maps", type=Path, help="folder of <failure>.h5 (the agreement test's maps)")
    ap.add_argument("failure")
    ap.add_argument("scenario", type=int, choices=(1, 2, 3))
    ap.add_argument("seed", type=int, help="the decision's trial seed (the test's: 500-511)")
    ap.add_argument("depth", type=int, help="random actions before the decision (0-2)")
    ap.add_argument("--candidate", type=int, help="the candidate to cut (default: the one that differs most)")
    ap.add_argument("--device", default=None, help="Warp device: cpu, or cuda:0 (default: the first CUDA device)")
    args = ap.parse_args()
    robot, maps, GpuSimConfig = setup("agreement_miss", (args.failure,), args.maps)
    found = decision_states(robot, maps, (args.scenario,), 1, args.depth + 1, 64, first_seed=args.seed)
    found = [d for d in found if d.depth == args.depth]
    if not found:
        sys.exit("agreement_miss: no such decision (fewer than 2 candidates there, or the trial stopped earlier)")
    d = found[0]
    sc = scenario(args.scenario, robot.profile.task_scale, "hard")
    ref_sim = make_simulator(robot, resolve_task(args.scenario, robot, "hard"), "cpu")

    def warp(n: int):  # MuJoCo Warp, one batch of n on another device
        cfg = GpuSimConfig(device=args.device, buckets=(n,)) if args.device else None
        return make_simulator(robot, resolve_task(args.scenario, robot, "hard"), "gpu", gpu_config=cfg)

    req = [(d.observation.robot_q, d.observation.objects, d.actions)]
    ref, new = ref_sim.simulate_many(req)[0], warp(len(d.actions)).simulate_many(req)[0]
    field = GoalField(sc, *table_bounds(robot))
    s_ref, s_new = score(sc, robot, ref, field), score(sc, robot, new, field)
    pick_ref, pick_new = int(np.argmin(s_ref)), int(np.argmin(s_new))
    diff = np.hypot(*(new[:, 0, :2] - ref[:, 0, :2]).T)
    print(f"{len(d.actions)} candidates; C MuJoCo picks {pick_ref}, MuJoCo Warp {pick_new}: "
          f"choice gap {100 * (s_ref[pick_new] - s_ref[pick_ref]):.2f} cm")  # fmt: skip
    for i in np.argsort(-diff)[:5]:
        print(f"  candidate {i} (edge {d.actions[i].edge}, {d.actions[i].route}): target ends {100 * diff[i]:.2f} cm "
              f"apart, C MuJoCo {ref[i, 0, :3].round(3)} score {s_ref[i]:.3f}, Warp {new[i, 0, :3].round(3)} score "
              f"{s_new[i]:.3f}")  # fmt: skip
    i = int(np.argmax(diff)) if args.candidate is None else args.candidate
    if not 0 <= i < len(d.actions):
        sys.exit(f"agreement_miss: --candidate {i}: give 0-{len(d.actions) - 1}")
    a = d.actions[i]
    n_pts = len(a.q)
    cuts = sorted(set(range(2, n_pts, max(1, n_pts // 60))) | {n_pts})
    cut = [replace(a, q=a.q[:k], qd=a.qd[:k]) for k in cuts]
    req = [(d.observation.robot_q, d.observation.objects, cut)]
    ref, new = ref_sim.simulate_many(req)[0], warp(len(cut)).simulate_many(req)[0]
    print(f"candidate {i}: {n_pts} control points, the transit's {a.transit_steps}; cut after k:")
    for k, r, w in zip(cuts, ref, new, strict=True):
        gap = np.hypot(*(r[0, :2] - w[0, :2]))
        print(f"  {k:4d}  C MuJoCo {r[0, :3].round(4)}  Warp {w[0, :3].round(4)}  {1000 * gap:8.2f} mm")


if __name__ == "__main__":
    main()
