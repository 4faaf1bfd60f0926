"""Figures of the Panda that must not change when lmjx changes how it represents robots: a
small case-2 map's edges and the trials planned on it.

`python tests/golden.py MAP OUT.json` writes them; tests/data/panda_golden.json was written
this way by the code before lmjx took any robot (commit 732f4a2, where the Panda was the
only arm), and tests/test_planning.py compares today's code with it.  One change since, made
on purpose: the edges' start IK became the Reach-Ability map's own program (one IK program
per build, issue 18), whose float32 rounding differs; of the 3,000 edges one start that
failed is now found (and that edge then hits the table): rejected 'ik' 778 -> 777 and
'table_collision' 723 -> 724; the valid edges, states and trials are as they were.  A second,
in issue 19: actions became ones a real arm could execute (transits clear of every object and
fixed obstacle, only edges whose arm comes into contact range of the target): on the small
map almost no edge passes, so the trials are now those of the planner tests' map
(conftest.PLAN_MAP: `python tests/golden.py SMALL_MAP OUT.json PLAN_MAP`), written by the
code of that change.  A third, also issue 19: a transit leaving a contact may no longer go
deeper into the scene's margins on its way out; Greedy's second action of the golden trial
went deeper (edge 724), it took edge 328 (final distance 0.2703 -> 0.2544 m).  A fourth, the
same day: an edge acts on the target only if the arm sweeps 5 mm into its box (was: comes
within 5 mm), a transit after a push first backs out along the edge (slowly, inside the
margins), and leaving a margin is checked box by box: all three trials changed (Random now
ends after one action with no feasible transit; Lazy and Greedy take edges 735, 724).  The
map figures are unchanged throughout.  Across machines (2026-11-24, a CPU with AVX-512 and
AMX): that one knife-edge start IK failed again (ik 778, table_collision 723), and the
Random trial's final distance came out 2 um from the file's: the tests allow exactly that
one start to go either way and 20 um on the final distance.  A fifth, the same day (issue 19,
the arm jammed after a push): a retreat whose way back to RETREAT_SLACK is blocked may stop
as soon as the arm is clear of every margin, and a blocked way to the park pose may dog-leg
(`TransitPlanner.to_park`); Lazy's and Greedy's trials keep their edges (735, 724), their
second transit is shorter (execution 14.62 -> 7.70 s, final distance 0.29445 -> 0.29423 m);
written on the AVX-512 CPU.  A sixth, 2026-11-25 (issue 19, transits brushing objects): a
transit leaving a contact may come only 0.2 mm nearer than it began (was 1 mm) and moves at a
tenth of the transits' speed inside the margins (was a quarter); the same edges, Lazy's and
Greedy's execution 7.70 -> 8.42 s, final distances within 6 um of the previous ones.  A
seventh, 2026-11-27 (issue 19, a transit that touched the tunnel's roof): a transit slows to
rest into each sharp corner of its path and speeds up out of it (`lmjx.planner.timelaw`); Random's
transit has none and is as it was; Lazy's and Greedy's second transit (the retreat, then on)
has one: the same edges, execution 8.42 -> 8.82 s, final distances 1 nm apart.  The
trials run with no push weight (`PlannerConfig.push_weight`, the default until 2026-11-27,
when it became 1) and no rescoring (`PlannerConfig.rescore_top`, 0 until 2026-11-27, then
8) and the playback servos (`PlannerConfig.servo`, the only model until 2026-11-27, then
"robot"): the file tests how the robot is represented, not the planner's defaults.
"""

from __future__ import annotations

import hashlib
import json
import sys

import numpy as np

MAP_ARGS = ("--failure", "case2", "--edges", "3000", "--cell", "0.05", "--seed", "1")  # build-map arguments
TRIAL = {"scenario": 1, "seed": 3, "max_actions": 2, "greedy_candidates": 8, "lazy_tries": 4}


def _digest(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def map_figures(path: str) -> dict:
    from lmjx.mapfile.read import load_map

    m = load_map(path)
    r, e = m.reach, m.edges
    return {
        "areas": {k: round(float(v), 6) for k, v in r.areas(True).items()},
        "labels": _digest(r.labels),
        "edges_valid": int(e.n_edges),
        "edges_sampled": int(m.edges_attrs["edges_sampled"]),
        "rejected": {k[len("rejected_") :]: int(v) for k, v in m.edges_attrs.items() if k.startswith("rejected_")},
        "states": len(e.q),
        "q_sum": float(np.sum(np.asarray(e.q[...], np.float64))),
        "q_abs_sum": float(np.sum(np.abs(np.asarray(e.q[...], np.float64)))),
    }


def trial_figures(path: str) -> dict:
    from lmjx.evaluation.trial import run_trial, setup_trial
    from lmjx.mapfile.read import load_map
    from lmjx.model.robot import load_robot
    from lmjx.sim.scenarios import resolve_task
    from lmjx.types import PlannerConfig

    robot = load_robot()
    m = load_map(path)
    out = {}
    for asm in ("random", "lazy", "greedy"):
        cfg = PlannerConfig(
            asm=asm, max_actions=TRIAL["max_actions"], greedy_candidates=TRIAL["greedy_candidates"],
            lazy_tries=TRIAL["lazy_tries"], push_weight=0.0, rescore_top=0,  # (the defaults until 2026-11-27)
            servo="playback",
        )  # fmt: skip
        res = run_trial(setup_trial(robot, m, resolve_task(TRIAL["scenario"], robot, "hard"), cfg, seed=TRIAL["seed"]))
        out[asm] = {
            "success": bool(res.success),
            "actions": int(res.actions),
            "edges": [int(s.edge) for s in res.steps],
            "final_distance_m": round(float(res.final_distance), 9),
            "execution_s": round(float(res.execution_s), 6),
        }
    return out


if __name__ == "__main__":
    figures = {"map": map_figures(sys.argv[1])}
    if "--map-only" not in sys.argv:
        figures["trials"] = trial_figures(sys.argv[3] if len(sys.argv) > 3 else sys.argv[1])
    with open(sys.argv[2], "w") as f:
        json.dump(figures, f, indent=1)
        f.write("\n")
