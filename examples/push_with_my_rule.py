"""Push the target of a scene file into its goal with a rule of my own, through lmjx's public API.

lmjx gives the map's edges over the target, the transits to them, a batched simulator and a
simulated "real" world; the choice of edge is this script's:
  * the edges over the target, the map's own and their copies turned about the arm's base
    joint (`MapFile.edges_over(region, turned=True)`, as lmjx's planner offers them), are
    ranked: first those whose interaction point starts behind the target (seen from the goal)
    in line with it and then moves toward the goal, furthest first (`MapFile.edge(i, turn)`:
    the point's path); then the others by how far the point moves toward the goal;
  * the best-ranked edges with a collision-free transit (`lmjx.transit`) are the candidates;
  * with --simulate K, the first K candidates are simulated (`lmjx.simulate`) and the one that
    leaves the target nearest the goal is taken; without, the first candidate;
  * it is executed in the simulated real world (`lmjx.SimulatedRealWorld`, an `lmjx.Executor`:
    a real robot's backend would take its place), and the whole action, from rest to rest,
    may be written out for a robot's controller (`lmjx.trajectory`, --export: JSON as a ROS
    JointTrajectory).

    python examples/push_with_my_rule.py maps/case2.h5 examples/my_bench.toml --simulate 8
    python examples/push_with_my_rule.py maps/case2.h5 1 --simulate 4    # the paper's scenario 1

(maps/case2.h5 is what `make run` builds.)  It imports nothing of lmjx but `lmjx` itself.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import lmjx


def ranked_edges(m: lmjx.MapFile, target: np.ndarray, goal: np.ndarray, half: float) -> list[tuple[int, float]]:
    """The edges over the target as (id, turn), those in line behind it that move toward the goal first."""
    ids, turns = m.edges_over((target[0] - half, target[1] - half, target[0] + half, target[1] + half), turned=True)
    way = (goal - target) / max(float(np.linalg.norm(goal - target)), 1e-9)
    side = np.array([-way[1], way[0]])

    def rank(i: int, turn: float) -> tuple[bool, float]:
        p = m.edge(i, turn=turn).p[:, :2]
        toward = float((p[-1] - p[0]) @ way)
        in_line = (p[0] - target) @ way < -half and abs((p[0] - target) @ side) < half
        return (bool(in_line and toward > 0), toward)

    pairs = [(int(i), float(t)) for i, t in zip(ids, turns, strict=True)]
    return sorted(pairs, key=lambda e: rank(*e), reverse=True)


def candidates(m, task, obs, last, ranked: list[tuple[int, float]], want: int, tries: int) -> list[lmjx.Transit]:
    """The first `want` of the ranked edges with a transit from where the arm is (of at most `tries`)."""
    found = []
    for i, turn in ranked[:tries]:
        t = lmjx.transit(m.robot, task, obs.robot_q, m.edge(i, turn=turn), objects=obs.objects, after=last)
        if t:
            found.append(t)
            if len(found) == want:
                break
    return found


def run(map_path: str, scene: str, seed: int = 0, simulate: int = 0, actions: int | None = None,
        export: str | None = None, tries: int = 48) -> dict:  # fmt: skip
    """One trial of the rule (`scene`: a scene file, or the number of one of the paper's
    scenarios); returns what happened."""
    m = lmjx.load_map(map_path)
    path = lmjx.shipped_scene(int(scene), "paper") if str(scene).isdigit() else scene
    task = lmjx.load_scene(path, map_file=m)  # checked: geometry, and the goal where the map reaches
    goal = np.asarray(task.scenario.goal_center)
    half = float(task.scenario.target.half[0])
    world = lmjx.SimulatedRealWorld(m.robot, seed)
    obs = world.reset(task.layout(seed), lmjx.park_pose(m))
    last, done, end = None, [], "budget"
    for _ in range(actions or task.budget):
        if task.in_goal(obs.objects[0, :2]):
            end = "goal"
            break
        ranked = ranked_edges(m, obs.objects[0, :2], goal, half)
        found = candidates(m, task, obs, last, ranked, max(1, simulate), tries)
        if not found:
            end = "no edge with a transit"
            break
        pick = found[0]
        if simulate > 1 and len(found) > 1:
            ends = lmjx.simulate(task, obs, [t.action for t in found])  # (candidates, objects, 7)
            pick = found[int(np.argmin(np.linalg.norm(ends[:, 0, :2] - goal, axis=1)))]
        if export:  # the whole action, from rest to rest, for a joint trajectory controller
            name = f"action{len(done) + 1}_edge{pick.edge}_turn{round(np.degrees(pick.turn))}.json"
            lmjx.trajectory(pick, 0.01, joint_names=list(m.robot.joint_names)).write(Path(export) / name)
        obs = world.execute(pick.action)
        last = pick.action
        done.append((pick.edge, pick.turn))
    else:
        if task.in_goal(obs.objects[0, :2]):
            end = "goal"
    truth = world.truth()
    return {
        "success": task.in_goal(truth[0, :2]),
        "end": end,
        "edges": done,
        "distance_m": float(np.linalg.norm(truth[0, :2] - goal)),
        "robot_time_s": obs.time,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("map", help="a map file (lmjx build-map)")
    p.add_argument("scene", nargs="?", default=str(Path(__file__).with_name("my_bench.toml")),
                   help="a scene file, or 1, 2, 3: the paper's scenario")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="the trial's seed: layout and 'real' world (default 0)")
    p.add_argument("--simulate", type=int, default=0, metavar="K", help="simulate K candidates per decision")
    p.add_argument("--actions", type=int, metavar="N", help="at most N actions (default: the scene's budget)")
    p.add_argument("--tries", type=int, default=48, metavar="N", help="transits searched per decision (default 48)")
    p.add_argument("--export", metavar="DIR", help="write each executed action's trajectory there (JSON)")
    args = p.parse_args(argv)
    try:
        r = run(args.map, args.scene, args.seed, args.simulate, args.actions, args.export, args.tries)
    except lmjx.LmjxError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    end = "success" if r["success"] else "failure"
    edges = [f"{e}" + (f" turned {np.degrees(t):+.0f} deg" if t else "") for e, t in r["edges"]]
    print(f"{end} ({r['end']}) after {len(edges)} actions {edges}; target {r['distance_m'] * 100:.1f} cm "
          f"from the goal's centre; robot time {r['robot_time_s']:.1f} s")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
