"""Which of the "real" world's differences moves a push's target away from the planner's
prediction?  (The sixteenth session's measurement before choosing a lever:
benchmarks/evaluation_plan_2026-11-28.md.)

Decision states of one hard-set scenario (`lmjx.evaluation.agreement.decision_states`: a trial's start
and the states after one and two random actions, 16 candidates each), each candidate
simulated with C MuJoCo from the observed state with the planner's physics and with one of
the "real" world's differences alone (its servos; its objects' frictions and masses; its
capsules' radius offset with the robot-table contacts), and with all of them (the "real"
world's physics of that trial).  Then the planner simulating with the robot's own servos
(`--servo robot`) against all of them.  Printed: per decision, the median of where the target
ends apart from the planner's prediction; per difference, the median and p90 over all.

    JAX_PLATFORMS=cpu python benchmarks/servo_gap_2026-11-27/gap.py MAP SCENARIO SEEDS FIRST_SEED
"""

from __future__ import annotations

import sys
import time

import numpy as np

from lmjx.evaluation.agreement import decision_states
from lmjx.evaluation.trial import planner_physics
from lmjx.mapfile.read import load_map
from lmjx.model.robot import as_robot
from lmjx.sim.cpu import CpuSimulator
from lmjx.sim.realworld import real_physics
from lmjx.sim.scenarios import scenario
from lmjx.sim.scene import Physics, build_scene


def target_ends(robot, sc, physics: Physics, d) -> np.ndarray:
    """Where each candidate of decision d leaves the target (n, 2), simulated with `physics`."""
    sim = CpuSimulator(build_scene(robot, sc, physics))
    return sim.simulate(d.observation.robot_q, d.observation.objects, d.actions)[:, 0, :2]


def main() -> None:
    robot = as_robot("panda")
    path, s, seeds, first = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    mf = load_map(path)
    t0 = time.time()
    decs = decision_states(robot, {mf.failure.spec: mf}, (s,), seeds, 3, 16, first_seed=first)
    print(f"{len(decs)} decisions in {time.time() - t0:.0f} s", flush=True)
    sc = scenario(s, robot.profile.task_scale, "hard")
    servo = planner_physics(robot, "robot")
    gaps: dict[str, list[np.ndarray]] = {k: [] for k in ("servo", "friction+mass", "capsules", "all", "robot vs all")}
    for d in decs:
        full = real_physics(robot, len(sc.movable), np.random.default_rng(10_000 + d.seed))  # the trial's "real" world
        variants = {
            "servo": servo,
            "friction+mass": Physics(
                friction_scale=full.friction_scale, mass_scale=full.mass_scale, table_friction=full.table_friction
            ),
            "capsules": Physics(robot_radius_offset=full.robot_radius_offset, robot_table_contacts=True),
            "all": full,
        }
        base = target_ends(robot, sc, Physics(), d)
        ends = {k: target_ends(robot, sc, ph, d) for k, ph in variants.items()}
        for k, e in ends.items():
            gaps[k].append(np.hypot(*(e - base).T))
        gaps["robot vs all"].append(np.hypot(*(ends["all"] - ends["servo"]).T))
        med = {k: round(float(np.median(v[-1])) * 1000, 2) for k, v in gaps.items()}
        print(d.seed, d.depth, len(d.actions), med, flush=True)
    for k, v in gaps.items():
        e = np.concatenate(v) * 1000
        against = "the planner with --servo robot" if k == "robot vs all" else "the planner (playback)"
        print(f"{k:14s} against {against}: n={len(e)} median {np.median(e):.1f} mm, p90 {np.percentile(e, 90):.1f} mm")


if __name__ == "__main__":
    main()
