"""Greedy's cost of a path on the table: how rarely the map's edges push toward the goal there.

Greedy scores a candidate by the target's path length to the goal (`GoalField`).  Behind
the tunnel's wall that score is blind to where the arm can act: a push that leaves the
target beside the opening's far edge looks as good as one that leaves it in front of the
opening, although from the first no edge of the map pushes it on.  The map's push counts
(`lmjx.mapfile.pushmap`: per reach cell, the edges that can push a target there toward the
goal) become a cost multiplier per point of the table here (`push_weights`: 1 where pushes
toward the goal are as common as on the median cell, more where rarer), and
`GoalField(weights=...)` integrates it along the path: the score becomes the cost of the
cheapest way to the goal through places the map can push from.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy import ndimage

from lmjx.reach.reachability import ReachResult


def push_weights(
    counts: np.ndarray, reach: ReachResult, reach_radius: float, strength: float
) -> Callable[[np.ndarray], np.ndarray]:
    """Cost multipliers at table points (n, 2): 1 + strength * ln(median / (count + 1)), at
    least 1, where count is the sum of `counts` over the reach cells within `reach_radius`
    (the target's half size and the planner's margin: the capsules that can touch a target
    centred there) and median is that sum's median over the cells where it is positive."""
    cell = reach.config.cell
    r = max(0, math.ceil(reach_radius / cell))
    size = 2 * r + 1
    near = ndimage.uniform_filter(counts.astype(np.float64), size=size, mode="constant") * size * size
    near = np.rint(near)
    positive = near[near > 0]
    ref = float(np.median(positive)) if len(positive) else 1.0
    w = 1.0 + strength * np.maximum(0.0, np.log(ref / (near + 1.0)))
    x0, y0 = reach.xs[0] - cell / 2, reach.ys[0] - cell / 2
    ny, nx = counts.shape

    def at(pts: np.ndarray) -> np.ndarray:
        ix = np.clip(np.floor((pts[:, 0] - x0) / cell).astype(np.int64), 0, nx - 1)
        iy = np.clip(np.floor((pts[:, 1] - y0) / cell).astype(np.int64), 0, ny - 1)
        return w[iy, ix]

    return at
