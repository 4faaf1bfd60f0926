"""How far the target is from its goal, around the fixed obstacles: a navigation function on
the table, used to score candidate actions.

The plain distance to the goal misleads a greedy planner behind a wall: a push that brings the
target to the tunnel's entrance but sideways looks no better than one that leaves it in a
corner of the wall.  `GoalField` holds, on a grid over the table, the length of the shortest
path a cube-sized object's centre can take to the goal region's centre (Dijkstra on the
8-connected grid, whose paths are at most 8 % longer than the true ones; the fixed obstacles
that reach below the cube's top, grown by the target's footprint radius (a box's half
diagonal, a cylinder's radius), are walls: a box as its grown rectangle, a cylinder as its
grown circle).  Inside a wall
the value is that of the nearest free cell plus twice the distance to it.  With no fixed
obstacles in the way it is the exact Euclidean distance to the goal's centre, so scenarios 1
and 3 are scored by plain distance.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph

from lmjx.sim.scenarios import Scenario, _corners


class GoalField:
    def __init__(
        self,
        sc: Scenario,
        table_lo: np.ndarray,
        table_hi: np.ndarray,
        cell: float = 0.005,
        weights: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> None:
        """`weights`: a cost per metre at table points (n, 2) -> (n,), at least 1 (None: 1
        everywhere, the path length); the field is then the cheapest way's cost
        (`lmjx.mapfile.pushmap`)."""
        self.cell = cell
        self.lo = np.asarray(table_lo, np.float64)[:2]
        nx, ny = (np.ceil((np.asarray(table_hi)[:2] - self.lo) / cell).astype(int) + 1).tolist()
        xs = self.lo[0] + cell * np.arange(nx)
        ys = self.lo[1] + cell * np.arange(ny)
        gx, gy = np.meshgrid(xs, ys, indexing="xy")  # (ny, nx)
        pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
        half = sc.target.half
        grow = sc.target.footprint_radius  # (a box's half diagonal: math.hypot(half[0], half[1]))
        blocked = np.zeros(len(pts), bool)
        for f in sc.fixed:
            if f.zc - f.half[2] >= 2 * half[2]:
                continue  # above the cube (a roof)
            if f.shape == "box":
                blocked |= _inside(_corners(f.half, f.x, f.y, f.yaw, grow), pts)
            else:  # a cylinder: its circle grown by the target's reach
                blocked |= np.hypot(pts[:, 0] - f.x, pts[:, 1] - f.y) <= f.half[0] + grow
        blocked = blocked.reshape(ny, nx)
        self.goal = np.asarray(sc.goal_center, np.float64)
        self.euclidean = not blocked.any() and weights is None
        w = np.ones((ny, nx)) if weights is None else np.asarray(weights(pts), np.float64).reshape(ny, nx)
        goal = np.zeros_like(blocked)
        goal[round((self.goal[1] - self.lo[1]) / cell), round((self.goal[0] - self.lo[0]) / cell)] = True
        dist = _shortest_paths(~blocked, goal & ~blocked, cell, w)
        # cells in walls (or cut off): the nearest reachable cell's value + 2 x the way there
        bad = ~np.isfinite(dist)
        if bad.any():
            dt, (iy, ix) = ndimage.distance_transform_edt(bad, sampling=cell, return_indices=True)
            dist = np.where(bad, dist[iy, ix] + 2.0 * dt, dist)
        self.values = dist  # (ny, nx)
        self.shape = (ny, nx)

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        """Path length to the goal's centre (...,) for centres xy (..., 2), bilinearly interpolated;
        points off the grid take the nearest edge's value plus their distance to the grid."""
        xy = np.asarray(xy, np.float64)
        if self.euclidean:
            return np.hypot(xy[..., 0] - self.goal[0], xy[..., 1] - self.goal[1])
        f = (xy - self.lo) / self.cell
        ny, nx = self.shape
        fc = np.stack([np.clip(f[..., 0], 0, nx - 1), np.clip(f[..., 1], 0, ny - 1)], axis=-1)
        outside = np.hypot(*(f - fc).transpose(-1, *range(f.ndim - 1))) * self.cell
        i0 = np.minimum(np.floor(fc).astype(int), [nx - 2, ny - 2])
        t = fc - i0
        v = self.values
        x0, y0 = i0[..., 0], i0[..., 1]
        a = v[y0, x0] * (1 - t[..., 0]) + v[y0, x0 + 1] * t[..., 0]
        b = v[y0 + 1, x0] * (1 - t[..., 0]) + v[y0 + 1, x0 + 1] * t[..., 0]
        return a * (1 - t[..., 1]) + b * t[..., 1] + outside


def _inside(poly: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Points (n, 2) inside a convex polygon (4, 2) given counter-clockwise or clockwise."""
    u, w = poly[1] - poly[0], poly[2] - poly[1]
    sign = 1.0 if u[0] * w[1] - u[1] * w[0] > 0 else -1.0  # the polygon's orientation
    out = np.ones(len(pts), bool)
    for i in range(len(poly)):
        e = poly[(i + 1) % len(poly)] - poly[i]
        out &= sign * (e[0] * (pts[:, 1] - poly[i, 1]) - e[1] * (pts[:, 0] - poly[i, 0])) >= 0
    return out


def _shortest_paths(free: np.ndarray, sources: np.ndarray, cell: float, w: np.ndarray) -> np.ndarray:
    """Path costs (ny, nx) from the source cells through free cells (8-connected), a step
    costing its length times the mean of its two cells' weights `w` (ny, nx)."""
    ny, nx = free.shape
    idx = np.arange(ny * nx).reshape(ny, nx)
    rows, cols, cost = [], [], []
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        ya, yb = slice(0, ny - dy), slice(dy, ny)
        x0, x1 = max(0, -dx), nx - max(0, dx)
        xa, xb = slice(x0, x1), slice(x0 + dx, x1 + dx)
        ok = free[ya, xa] & free[yb, xb]
        rows.append(idx[ya, xa][ok])
        cols.append(idx[yb, xb][ok])
        cost.append(cell * math.hypot(dx, dy) * 0.5 * (w[ya, xa][ok] + w[yb, xb][ok]))
    n = ny * nx
    src = n  # a virtual node joined to every source cell at no cost
    s_idx = idx[sources]
    rows.append(np.full(len(s_idx), src))
    cols.append(s_idx)
    cost.append(np.full(len(s_idx), 1e-12))
    g = sparse.coo_matrix((np.concatenate(cost), (np.concatenate(rows), np.concatenate(cols))), shape=(n + 1, n + 1))
    d = csgraph.dijkstra(g.tocsr(), directed=False, indices=src)
    return d[:n].reshape(ny, nx)
