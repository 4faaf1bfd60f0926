"""The whole-arm spatial index as numpy computes it on the host: the reference the device
kernel (`lmjx.edges.index`, `kernels.index`) must match pair for pair.  Every state's
table-checked capsules in float64 (from the float32 capsule ends of the capsule program),
rasterized, then made unique with `np.unique`.
"""

from __future__ import annotations

import numpy as np

from lmjx.edges.index import capsule_ends_kernel
from lmjx.model.robot import Robot
from lmjx.reach.reachability import ReachResult

# States whose capsules are computed at a time; the largest radius among the low capsules of
# these states sets the cells looked at around a sample.
INDEX_STATES = 1 << 16


def reference_pairs(
    reach: ReachResult, robot: Robot, q: np.ndarray, length: np.ndarray, height: float
) -> tuple[np.ndarray, np.ndarray]:
    """(cell, edge) pairs, unique and sorted by cell then edge: the edges (numbered as
    `length` lists them; `q` holds their states, flat) during which any of the arm's
    table-checked capsules, swept over the edge's states, comes within its radius of a reach
    cell's square with its lowest surface at most `height` above the table.  Each capsule's
    low part (the stretch of its axis whose surface below is under `height`) is sampled
    every half cell; a cell counts when a sample lies within the capsule's radius of its
    square."""
    ny, nx = reach.labels.shape
    cell = reach.config.cell
    grid = (reach.xs[0] - cell / 2, reach.ys[0] - cell / 2, cell, nx, ny)
    if len(q) == 0:
        return np.zeros(0, np.int32), np.zeros(0, np.int32)
    ends = capsule_ends_kernel(robot).run(np.asarray(q, np.float32))
    return reference_pairs_of_ends(grid, robot, ends["a"], ends["b"], length, height)


def reference_pairs_of_ends(
    grid: tuple[float, float, float, int, int],
    robot: Robot,
    ends_a: np.ndarray,
    ends_b: np.ndarray,
    length: np.ndarray,
    height: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The same pairs from the states' capsule ends (S, nc, 3) float32 on a grid (x0, y0,
    cell, nx, ny): its lower corner, cell, cells along x and y."""
    x0, y0, cell, nx, ny = grid
    arm = robot.arm
    caps = np.asarray(arm.table_caps)
    if len(ends_a) == 0 or len(caps) == 0:
        return np.zeros(0, np.int32), np.zeros(0, np.int32)
    r_cap = np.asarray(arm.cap_r, np.float64)[caps]
    edge_of_row = np.repeat(np.arange(len(length), dtype=np.int64), length)
    width = max(1, len(length))
    keys: list[np.ndarray] = []
    for s0 in range(0, len(ends_a), INDEX_STATES):
        a = ends_a[s0 : s0 + INDEX_STATES][:, caps].astype(np.float64)  # (m, nc, 3)
        b = ends_b[s0 : s0 + INDEX_STATES][:, caps].astype(np.float64)
        za = a[..., 2] - arm.table_z - r_cap
        zb = b[..., 2] - arm.table_z - r_cap
        row, cap = np.nonzero(np.minimum(za, zb) <= height)
        if not len(row):
            continue
        a, b, za, zb = a[row, cap], b[row, cap], za[row, cap], zb[row, cap]
        # the low stretch [t0, t1] of each axis (z falls linearly along it)
        dz = zb - za
        with np.errstate(divide="ignore", invalid="ignore"):
            t_h = np.where(np.abs(dz) > 1e-12, (height - za) / dz, 0.0)
        t0 = np.where(za <= height, 0.0, np.clip(t_h, 0.0, 1.0))
        t1 = np.where(zb <= height, 1.0, np.clip(t_h, 0.0, 1.0))
        pa = a[:, :2] + t0[:, None] * (b[:, :2] - a[:, :2])
        pb = a[:, :2] + t1[:, None] * (b[:, :2] - a[:, :2])
        k = np.ceil(np.hypot(*(pb - pa).T) / (cell / 2)).astype(np.int64) + 1  # samples per stretch
        owner = np.repeat(np.arange(len(k)), k)
        first = np.concatenate([[0], np.cumsum(k)[:-1]])
        frac = (np.arange(len(owner)) - first[owner]) / np.maximum(k[owner] - 1, 1)
        pts = pa[owner] + frac[:, None] * (pb[owner] - pa[owner])
        rad = r_cap[cap[owner]]
        edge = edge_of_row[s0 + row[owner]]
        # every cell whose square lies within the radius of a sample
        reach_cells = int(np.ceil(rad.max() / cell))
        ix = np.floor((pts[:, 0] - x0) / cell).astype(np.int64)
        iy = np.floor((pts[:, 1] - y0) / cell).astype(np.int64)
        for dy in range(-reach_cells, reach_cells + 1):
            for dx in range(-reach_cells, reach_cells + 1):
                cx, cy = ix + dx, iy + dy
                gx = np.maximum(np.abs(pts[:, 0] - (x0 + (cx + 0.5) * cell)) - cell / 2, 0.0)
                gy = np.maximum(np.abs(pts[:, 1] - (y0 + (cy + 0.5) * cell)) - cell / 2, 0.0)
                hit = (gx * gx + gy * gy <= rad * rad) & (cx >= 0) & (cx < nx) & (cy >= 0) & (cy < ny)
                keys.append(np.unique((cy[hit] * nx + cx[hit]) * width + edge[hit]))
    if not keys:
        return np.zeros(0, np.int32), np.zeros(0, np.int32)
    flat = np.unique(np.concatenate(keys))
    return (flat // width).astype(np.int32), (flat % width).astype(np.int32)
