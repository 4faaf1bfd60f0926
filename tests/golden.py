"""Figures of the Panda that must not change when lmjx changes how it represents robots: a
small case-2 map's edges and the trials planned on it.

`python tests/golden.py SMALL_MAP OUT.json PLAN_MAP` writes them: the figures of the small map
(`MAP_ARGS`, conftest.SMALL_MAP) and three trials, one per ASM (`TRIAL`), on the planner tests'
map (conftest.PLAN_MAP), where edges pass the planner's contact and clearance tests.
tests/data/panda_golden.json holds them; its map figures were written by the code before lmjx
took any robot (commit 732f4a2, where the Panda was the only arm), and its trials are written
again, on purpose, whenever what the planner's actions do changes (the file's git log says when
and why).  tests/test_planning.py compares today's code with it.  Across CPUs one start IK of
the 3,000 lies on a float32 knife edge (found or not: rejected 'ik' 777 or 778, the edge then
hitting the table or not) and the Random trial's final distance differs by 2 um: the tests
allow exactly that start to go either way and 20 um on the final distance.  The trials run
with no push weight, no rescoring, the playback servos and the map's edges alone (`push_weight=0`,
`rescore_top=0`, `servo="playback"`, `turn_edges=False`): the file tests how the robot is
represented, not the planner's defaults.
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
    from lmjx.mapfile.read import load_map
    from lmjx.model.robot import load_robot
    from lmjx.planner.trial import run_trial, setup_trial
    from lmjx.sim.scenarios import resolve_task
    from lmjx.types import PlannerConfig

    robot = load_robot()
    m = load_map(path)
    out = {}
    for asm in ("random", "lazy", "greedy"):
        cfg = PlannerConfig(
            asm=asm, max_actions=TRIAL["max_actions"], greedy_candidates=TRIAL["greedy_candidates"],
            lazy_tries=TRIAL["lazy_tries"], push_weight=0.0, rescore_top=0,  # (module docstring)
            servo="playback", turn_edges=False,
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
