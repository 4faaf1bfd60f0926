"""Why the hard set's trial 1005 (case 1, clutter, Greedy) ends "no feasible transit" after one
push on the GPU: its first action replayed on the CPU, then every way out of where the arm
stands asked for (the sixteenth session; docs/EVALUATION.md).

The GPU run's first pick was edge 12990 of the GPU-built case-1 map (88 states, a direct
transit; the target moved 14.33 cm).  The CPU-built map (`lmjx build-map --failure case1
--edges 1000000 --seed 0` with JAX_PLATFORMS=cpu) holds the same edge: replayed from the
trial's start in the trial's "real" world it moves the target as far, and the next decision
finds no action, with the GPU run's tally to the edge (35,611 tested, 30,558 starts blocked,
4,380 unusable, 673 with no transit).  Then: the arm's slack to every box's margin, the retreat
along the edge (and each box's slack along the way back), the escape's first steps, and the
planner's prediction of the same push (both servo models) with the ways out in the predicted
scene.

    JAX_PLATFORMS=cpu python benchmarks/replay_1005_2026-11-27/replay.py CASE1_MAP
"""

from __future__ import annotations

import sys

import numpy as np

from lmjx.evaluation.trial import make_simulator, setup_trial
from lmjx.mapfile.read import load_map
from lmjx.model.robot import load_robot
from lmjx.planner.clearance import JAM_MARGIN, LEAVE_TOLERANCE, OBJECT_MARGIN
from lmjx.planner.escape import ESCAPE_STEP
from lmjx.planner.transit import after_executing
from lmjx.sim.scenarios import resolve_task
from lmjx.types import PlannerConfig

EDGE, SEED, SCENARIO = 12990, 1005, 1


def main() -> None:
    robot = load_robot()
    m = load_map(sys.argv[1])
    task = resolve_task(SCENARIO, robot, "hard")
    st = setup_trial(robot, m, task, PlannerConfig(asm="greedy", greedy_candidates=32), SEED)
    p, tp = st.planner, st.planner.transits
    obs = st.world.reset(st.layout, tp.park)
    tp.set_scene(p.sc, obs.objects)
    act = tp.action(m.edges, EDGE, obs.robot_q)
    print(f"edge {EDGE}: route {act.route}, {act.edge_states} states")
    after = st.world.execute(act)
    print(f"target moved {after.target_moved_m:.4f} m, to {np.round(after.objects[0, :2], 4)}")
    came_from, trail = after_executing(act, obs.robot_q[None].copy(), m.edges.q_start.dtype)
    p.came_from, p.trail, p.futile = came_from, trail, {}
    p.draws = np.random.default_rng([SEED, 1])
    nxt, rec = p.choose(after, np.random.default_rng(0))
    print("next decision:", "no action" if nxt is None else (nxt.edge, nxt.route), rec.no_action)

    tp.set_scene(p.sc, after.objects)
    q = after.robot_q.astype(np.float64)
    names = [b.name for b in p.sc.movable]
    slack = np.round(tp.scene_slacks(q[None])[0], 4)
    print("the arm's slack to each margin [m]:", dict(zip(names, slack.tolist(), strict=True)))
    print("retreat:", tp.retreat(q, came_from) is not None, " to park:", tp.to_park(q) is not None,
          " escape:", tp.escape(q) is not None)  # fmt: skip
    path = np.asarray(came_from, np.float64)
    j = int(np.argmin(np.abs(path - q).max(axis=1)))
    back = tp.scene_slacks(path[max(j - 1, 0) :: -1])
    for k, name in enumerate(names):
        print(f"  the way back along the edge, {name}'s slack every 2nd state:", np.round(back[:30:2, k], 4))
    dirs = tp.escape_directions(len(q))
    relax = (OBJECT_MARGIN - JAM_MARGIN) * tp.scene.movable
    start = tp.scene_slacks(q[None])[0] + relax
    then = tp.scene_slacks(np.clip(q + ESCAPE_STEP * dirs, robot.lower, robot.upper)) + relax
    ok = np.where(start >= 0, then >= 0, then >= start - LEAVE_TOLERANCE).all(axis=1)
    print(f"escape's first step: {int(ok.sum())} of {len(dirs)} directions go no deeper into any margin")

    for servo in ("playback", "robot"):
        tp.set_scene(p.sc, obs.objects)
        pred = make_simulator(robot, task, "cpu", servo=servo).simulate(obs.robot_q, obs.objects, [act])[0]
        tp.set_scene(p.sc, pred)
        end = path[-1]
        slack = np.round(tp.scene_slacks(end[None])[0], 4)
        print(f"predicted ({servo}): target at {np.round(pred[0, :2], 4)}, slacks {slack}, "
              f"retreat {tp.retreat(end, came_from) is not None}, escape {tp.escape(end) is not None}")  # fmt: skip


if __name__ == "__main__":
    main()
