"""The map's spatial index: for each cell of the reach map, the edges during which the whole
arm (its table-checked capsules, swept over the edge's states) can touch an object there.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from lmjx.model.robot import Robot
from lmjx.reach.reachability import ReachResult
from lmjx.runtime.batching import ChunkedKernel, backend

# States whose capsules are computed at a time when indexing (bounds the host memory a
# chunk's index needs: about 100 MB for the Panda).
INDEX_STATES = 1 << 16
_ENDS: dict[tuple[str, int], Any] = {}  # (model hash, chunk) -> its capsule-ends program
_ENDS_LOCK = threading.Lock()


def capsule_ends_kernel(robot: Robot, chunk: int | None = None):
    """jit(vmap(capsule_ends)) for `robot`, one per process and chunk (shared by the packing
    threads).  `chunk`: configurations per call (default: 32,768 on an accelerator, 1,024 on
    the CPU, for the map's index; the planner's checks on the CPU hold a few dozen and ask
    for a smaller one, `actions.SMALL_CHUNK`)."""
    from kernels.collision import capsule_ends

    if chunk is None:
        chunk = 1 << 15 if backend() != "cpu" else 1024
    with _ENDS_LOCK:
        if (robot.model_hash, chunk) not in _ENDS:

            def one(q):
                return capsule_ends(robot.arm, q)

            _ENDS[robot.model_hash, chunk] = ChunkedKernel(
                ("capsule_ends", robot.model_hash), one, [], [(np.float32, (robot.nq,))], chunk
            )
        return _ENDS[robot.model_hash, chunk]


def arm_index_pairs(
    reach: ReachResult, robot: Robot, q: np.ndarray, length: np.ndarray, height: float
) -> tuple[np.ndarray, np.ndarray]:
    """(cell, edge) pairs, unique and sorted by cell then edge: the edges (numbered as
    `length` lists them; `q` holds their states, flat) during which any of the arm's
    table-checked capsules, swept over the edge's states, comes within its radius of a reach
    cell's square with its lowest surface at most `height` above the table: the whole arm
    can touch an object of that height there (the paper's edges that "intersect the
    object").  Each capsule's low part (the stretch of its axis whose surface below is under
    `height`) is sampled every half cell; a cell counts when a sample lies within the
    capsule's radius of its square."""
    ny, nx = reach.labels.shape
    cell = reach.config.cell
    x0 = reach.xs[0] - cell / 2
    y0 = reach.ys[0] - cell / 2
    arm = robot.arm
    caps = np.asarray(arm.table_caps)
    if len(q) == 0 or len(caps) == 0:
        return np.zeros(0, np.int32), np.zeros(0, np.int32)
    r_cap = np.asarray(arm.cap_r, np.float64)[caps]
    edge_of_row = np.repeat(np.arange(len(length), dtype=np.int64), length)
    width = max(1, len(length))
    kernel = capsule_ends_kernel(robot)
    keys: list[np.ndarray] = []
    for s0 in range(0, len(q), INDEX_STATES):
        ends = kernel.run(np.asarray(q[s0 : s0 + INDEX_STATES], np.float32))
        a = ends["a"][:, caps].astype(np.float64)  # (m, nc, 3)
        b = ends["b"][:, caps].astype(np.float64)
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


def csr(cells: np.ndarray, edges: np.ndarray, n_cells: int) -> tuple[np.ndarray, np.ndarray]:
    """CSR offsets (n_cells + 1,) and edge ids of (cell, edge) pairs sorted by cell."""
    offset = np.zeros(n_cells + 1, np.int64)
    offset[1:] = np.cumsum(np.bincount(cells, minlength=n_cells))
    return offset, edges.astype(np.int32)
