"""`lmjx.simulate` with sim="gpu" (MuJoCo Warp) against sim="cpu" (C MuJoCo), through the public API only.

On a map and a scene file (default: examples/my_bench.toml), the edges over the target are
turned into actions with `lmjx.transit` (the first --edges of them tried, up to --actions kept), simulated from the same
observation on both simulators, and compared: where the target ends (median and largest
distance, how many within 1 cm) and the time of one batched call each (after a first call
that makes and compiles the simulators).

    python benchmarks/simulate_api.py MAP [--scene FILE] [--edges 300] [--actions 64] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import lmjx


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map")
    ap.add_argument("--scene", default="examples/my_bench.toml")
    ap.add_argument("--edges", type=int, default=300)
    ap.add_argument("--actions", type=int, default=64)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    m = lmjx.load_map(a.map)
    task = lmjx.load_scene(a.scene, map_file=m)
    layout = task.layout(seed=a.seed)
    x, y = layout.poses[0, :2]
    half = task.scenario.target.half[0] + 0.01
    over = m.edges_over((x - half, y - half, x + half, y + half))
    q_park = lmjx.park_pose(m)
    found = [lmjx.transit(m.robot, task, q_park, m.edge(int(i)), objects=layout.poses) for i in over[: a.edges]]
    acts = [t.action for t in found if t][: a.actions]
    if not acts:
        raise SystemExit(f"no edge of {a.map} over the target of {a.scene} (seed {a.seed}) has a transit")
    obs = lmjx.SimulatedRealWorld(m.robot, seed=a.seed).reset(layout, q_park)
    ends, seconds = {}, {}
    for sim in ("cpu", "gpu"):
        lmjx.simulate(task, obs, acts[:2], sim=sim)  # made and compiled
        t0 = time.perf_counter()
        ends[sim] = lmjx.simulate(task, obs, acts, sim=sim)
        seconds[sim] = time.perf_counter() - t0
    d = np.linalg.norm(ends["cpu"][:, 0, :3] - ends["gpu"][:, 0, :3], axis=1)
    moved = np.linalg.norm(ends["cpu"][:, 0, :2] - layout.poses[0, :2], axis=1)
    print(
        f"{len(acts)} actions: cpu {seconds['cpu']:.3f} s, gpu {seconds['gpu']:.3f} s; target ends apart: median "
        f"{np.median(d):.2e} m, largest {d.max():.2e} m, within 1 cm {int((d < 0.01).sum())} of {len(d)}; the target "
        f"moved over 1 cm in {int((moved > 0.01).sum())}; all finite: {bool(np.isfinite(ends['gpu']).all())}"
    )


if __name__ == "__main__":
    main()
