"""The spatial index's host side: the pairs of the few items the device hands back as
borderline, by the index's reference arithmetic (float64 numpy, op for op as the device
kernel, `kernels.index`, repeats it), and the merge of consecutive edge groups' pairs.
"""

from __future__ import annotations

import numpy as np


def settle_items(
    a: np.ndarray,
    b: np.ndarray,
    r: np.ndarray,
    edge: np.ndarray,
    grid: tuple[float, float, float, int, int],
    height: float,
    table_z: float,
    reach: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The (cell, edge) pairs of (state, capsule) items, unique and sorted, by the index's
    reference arithmetic (float64 numpy on the float32 ends): the capsule's low stretch
    sampled every half cell, the cells within its radius of a sample among the `reach` cells
    on each side of the sample's.

    Args:
      a, b: (m, 3) float32 capsule axis ends; r: (m,) radii; edge: (m,) each item's edge;
      grid: its lower corner x0, y0, its cell, cells along x and y;
      reach: (m,) cells tested on each side of a sample's cell.
    """
    x0, y0, cell, nx, ny = grid
    a, b, r = np.asarray(a, np.float64), np.asarray(b, np.float64), np.asarray(r, np.float64)
    edge, reach = np.asarray(edge, np.int64), np.asarray(reach, np.int64)
    za = a[:, 2] - table_z - r
    zb = b[:, 2] - table_z - r
    low = np.minimum(za, zb) <= height
    a, b, za, zb, r, edge, reach = a[low], b[low], za[low], zb[low], r[low], edge[low], reach[low]
    if not len(a):
        return np.zeros(0, np.int32), np.zeros(0, np.int32)
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
    rad, e, near = r[owner], edge[owner], reach[owner]
    ix = np.floor((pts[:, 0] - x0) / cell).astype(np.int64)
    iy = np.floor((pts[:, 1] - y0) / cell).astype(np.int64)
    keys = []
    width = int(edge.max()) + 1
    most = int(near.max())
    for dy in range(-most, most + 1):
        for dx in range(-most, most + 1):
            cx, cy = ix + dx, iy + dy
            gx = np.maximum(np.abs(pts[:, 0] - (x0 + (cx + 0.5) * cell)) - cell / 2, 0.0)
            gy = np.maximum(np.abs(pts[:, 1] - (y0 + (cy + 0.5) * cell)) - cell / 2, 0.0)
            hit = (gx * gx + gy * gy <= rad * rad) & (cx >= 0) & (cx < nx) & (cy >= 0) & (cy < ny)
            hit &= (abs(dx) <= near) & (abs(dy) <= near)
            keys.append((cy[hit] * nx + cx[hit]) * width + e[hit])
    flat = np.unique(np.concatenate(keys))
    return (flat // width).astype(np.int32), (flat % width).astype(np.int32)


def merge_groups(groups: list[tuple[np.ndarray, np.ndarray]], n_cells: int) -> tuple[np.ndarray, np.ndarray]:
    """The pairs of consecutive edge groups, each in (cell, edge) order, in (cell, edge) order."""
    per_cell = np.sum([c for _, c in groups], axis=0)
    cells = np.repeat(np.arange(n_cells, dtype=np.int32), per_cell)
    if len(groups) == 1:
        return cells, groups[0][0]
    edges = np.empty(len(cells), np.int32)
    at = np.zeros(n_cells, np.int64)  # where each cell's pairs start
    at[1:] = np.cumsum(per_cell)[:-1]
    for group_edges, counts in groups:
        first = np.zeros(n_cells, np.int64)  # where each cell's pairs start in the group's
        first[1:] = np.cumsum(counts)[:-1]
        edges[np.repeat(at - first, counts) + np.arange(len(group_edges))] = group_edges
        at += counts
    return cells, edges
