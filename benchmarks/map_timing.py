"""Time whole Reach-Ability maps twice in one fresh process (first call compiles).

    python benchmarks/map_timing.py [failure ...]

Prints wall time, the map's own `seconds` (compilation excluded) and the part spent in the
IK kernels, to separate first-call costs from steady-state work.
"""

from __future__ import annotations

import sys
import time

t0 = time.perf_counter()
from lmjx.model.robot import load_robot  # noqa: E402
from lmjx.reach.reachability import ReachConfig, reach_map  # noqa: E402

robot = load_robot()
print(f"import + model load {time.perf_counter() - t0:.2f} s")
for failure in sys.argv[1:] or ["none"]:
    for i in range(2):
        t = time.perf_counter()
        res = reach_map(failure, ReachConfig(), robot=robot)
        wall = time.perf_counter() - t
        s = res.summary()
        print(
            f"{failure} run {i}: wall {wall:.3f} s, map {s['seconds']:.3f} s, kernels {s['kernel_seconds']:.3f} s, "
            f"compile {s['compile_seconds']:.2f} s on {s['device']}"
        )
