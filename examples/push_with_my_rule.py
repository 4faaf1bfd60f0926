"""Push the target of a scene file into its goal with a rule of my own, through lmjx's public API.

lmjx gives the map's edges over the target, the transits to them, a batched simulator and a
simulated "real" world; the choice of edge is this script's:
  * the edges over the target (`MapFile.edges_over`) are ranked by how far their interaction
    point moves toward the goal (`MapFile.edge`: the point's path);
  * the best-ranked edges with a collision-free transit (`lmjx.transit`) are the candidates;
  * with --simulate K, the first K candidates are simulated (`lmjx.simulate`) and the one that
    leaves the target nearest the goal is taken; without, the first candidate;
  * it is executed in the simulated real world (`lmjx.SimulatedRealWorld`, an `lmjx.Executor`:
    a real robot's backend would take its place), and its joint trajectory may be written out
    for a robot's controller (`lmjx.trajectory`, --export).

    python examples/push_with_my_rule.py maps/case2.h5 examples/my_bench.toml --simulate 8

(maps/case2.h5 is what `make run` builds.)  It imports nothing of lmjx but `lmjx` itself.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import lmjx


def ranked_edges(m: lmjx.MapFile, target: np.ndarray, goal: np.ndarray, half: float) -> list[int]:
    """The edges over the target, those whose interaction point moves furthest toward the goal first."""
    ids = m.edges_over((target[0] - half, target[1] - half, target[0] + half, target[1] + half))
    way = (goal - target) / max(float(np.linalg.norm(goal - target)), 1e-9)

    def toward_goal(i: int) -> float:
        p = m.edge(int(i)).p
        return float((p[-1, :2] - p[0, :2]) @ way)

    return sorted((int(i) for i in ids), key=toward_goal, reverse=True)


def candidates(m, task, obs, last, ranked: list[int], want: int, tries: int = 64) -> list[lmjx.Transit]:
    """The first `want` of the ranked edges with a transit from where the arm is (of at most `tries`)."""
    found = []
    for i in ranked[:tries]:
        t = lmjx.transit(m.robot, task, obs.robot_q, m.edge(i), objects=obs.objects, after=last)
        if t:
            found.append(t)
            if len(found) == want:
                break
    return found


def run(map_path: str, scene_path: str, seed: int = 0, simulate: int = 0, actions: int | None = None,
        export: str | None = None) -> dict:  # fmt: skip
    """One trial of the rule; returns what happened."""
    m = lmjx.load_map(map_path)
    task = lmjx.load_scene(scene_path, map_file=m)  # checked: geometry, and the goal where the map reaches
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
        found = candidates(m, task, obs, last, ranked, max(1, simulate))
        if not found:
            end = "no edge with a transit"
            break
        pick = found[0]
        if simulate > 1 and len(found) > 1:
            ends = lmjx.simulate(task, obs, [t.action for t in found])  # (candidates, objects, 7)
            pick = found[int(np.argmin(np.linalg.norm(ends[:, 0, :2] - goal, axis=1)))]
        if export:
            lmjx.trajectory(m.edge(pick.edge), 0.005).write(Path(export) / f"action{len(done) + 1}_edge{pick.edge}.csv")
        obs = world.execute(pick.action)
        last = pick.action
        done.append(pick.edge)
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
    p.add_argument("scene", nargs="?", default=str(Path(__file__).with_name("my_bench.toml")), help="a scene file")
    p.add_argument("--seed", type=int, default=0, help="the trial's seed: layout and 'real' world (default 0)")
    p.add_argument("--simulate", type=int, default=0, metavar="K", help="simulate K candidates per decision")
    p.add_argument("--actions", type=int, metavar="N", help="at most N actions (default: the scene's budget)")
    p.add_argument("--export", metavar="DIR", help="write each executed edge's trajectory there (CSV)")
    args = p.parse_args(argv)
    try:
        r = run(args.map, args.scene, args.seed, args.simulate, args.actions, args.export)
    except lmjx.LmjxError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    end = "success" if r["success"] else "failure"
    print(f"{end} ({r['end']}) after {len(r['edges'])} actions {r['edges']}; target {r['distance_m'] * 100:.1f} cm "
          f"from the goal's centre; robot time {r['robot_time_s']:.1f} s")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
