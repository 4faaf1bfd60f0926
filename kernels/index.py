"""The whole-arm spatial index, batched: (state, capsule) items to (cell, edge) marks.

For each state and table-checked capsule, the stretch of the capsule's axis whose surface
below is at most `height` above the table (its low stretch) is sampled every half cell, and
every reach cell whose square lies within the capsule's radius of a sample is marked for the
state's edge in a map of (edge, cell) marks; the pairs come out of it unique and in (cell,
edge) order (`extract_pairs`).  The marks are int32 (0 or 1), one per edge, row and column
of the grid widened by R columns on each side, so that each sample marks its 2R + 1 rows as
2R + 1 windows of 2R + 1 columns (a scatter-max of windows: a native atomic on a GPU, a
tight loop on a CPU).

Exactness.  The index is defined by float64 arithmetic on the float32 capsule ends (the
arithmetic of `lmjx.edges.index_settle.settle_items`).  These kernels repeat that arithmetic in
float64, op for op; what a device may still do differently (fuse a*b+c into one rounding,
compute a square root's hypotenuse otherwise) moves a value by a few units in the last place
(about 1e-16 relative).  Every discrete decision of the rasterization is therefore taken with
its margin to its threshold, and an item whose margin is below a tolerance (the `TOL_*`
constants, some 1e4 to 1e7 times the largest such difference) is *borderline*: it marks
nothing, and is handed back to the host to be settled with the reference arithmetic.  An item
that is not borderline takes every decision as the reference does.  The decisions:
  * low: min(za, zb) <= height, za = a_z - table_z - r (differences only: identical);
  * samples: k = ceil(L / (cell / 2)) + 1, L the stretch's length (a stretch of length
    exactly 0, when t0 == t1 or the axis is vertical, is exactly 0 everywhere);
  * a sample's cell: floor((p - lo) / cell) per axis;
  * a cell's test: gx^2 + gy^2 <= r^2, gx, gy the distances from the sample to the square.
The clip of the stretch's ends t0, t1 and the switch at |dz| = 1e-12 need no margin of their
own: t0, t1 are exact (a difference and a quotient of exact values), and a stretch whose ends
straddle `height` with |dz| < TOL_Z has its lower end within TOL_Z of `height`: borderline.

Fixed shapes: a pass takes the capsule ends of `states` states, compacts the candidate
items (lower end within TOL_Z of `height` or below) of a window starting at a given rank into
`items` slots, their samples into `samples` slots, and tests (2R + 1)^2 cells around each
sample.  What does not fit is left for the next pass (`next` in the pass's counts), so any
block of states is indexed by passes of one program.  Only the grid (nx, ny, R), the robot's
table capsules and these capacities are static; positions and heights are traced (float64,
passed as uint32 bit patterns so that no caller needs 64-bit types switched on).

Pure functions of arrays; the caller jits them with float64 enabled for the trace
(`lmjx.edges.index`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import lax

# Margins below which a decision is settled on the host.  Largest device/host difference of
# the value tested: about 1e-15 m for positions of a metre, 1e-13 in units of cells.
TOL_Z = 1e-9  # [m] lower end to `height`
TOL_K = 1e-9  # [half cells] stretch length to a whole number of half cells
TOL_U = 1e-9  # [cells] sample position to a cell boundary
TOL_S = 1e-12  # [m^2] squared distance to the square, to r^2
DZ_MIN = 1e-12  # [m] a stretch this flat (or flatter) has no crossing
PARAMS = ("x0", "y0", "cell", "half", "height", "table_z")  # float64 parameters, in this order


@dataclass(frozen=True)
class IndexShape:
    """The static part of the index programs: the table capsules, the grid and capacities."""

    caps: tuple[int, ...]  # the table-checked capsules (indices into the arm's capsules)
    radii: tuple[float, ...]  # their radii [m]
    nx: int
    ny: int
    reach: int  # R: cells tested on each side of a sample's cell
    states: int  # states per pass
    items: int  # candidate (state, capsule) items per pass
    samples: int  # samples per pass
    edges: int  # edges per map of marks (a multiple of 32)
    flags: int  # borderline items a pass reports

    @property
    def cells(self) -> int:
        return self.nx * self.ny

    @property
    def width(self) -> int:
        """Columns of a row of marks: the grid's and R on each side."""
        return self.nx + 2 * self.reach

    @property
    def size(self) -> int:
        """Marks in a map: edges x rows x columns."""
        return self.edges * self.ny * self.width


class PassOut(NamedTuple):
    marks: jnp.ndarray  # (size,) int32 marks, by edge, row, column (`IndexShape.size`)
    counts: jnp.ndarray  # (4,) int32: candidates, next (rank of the first item not done), borderline, samples
    low_caps: jnp.ndarray  # (nt,) bool: capsules low in some state of the block
    flag_ids: jnp.ndarray  # (flags,) int32 borderline items: state * nt + capsule (-1: none)
    flag_ends: jnp.ndarray  # (flags, 6) float32 their capsule ends a, b


class Window(NamedTuple):
    counts: jnp.ndarray  # (cells,) int32 edges per cell
    blocks: tuple[jnp.ndarray, ...]  # edge ids of pairs [off, off + capacity) in (cell, edge) order, -1 past the end


def params_words(values: dict[str, float]) -> np.ndarray:
    """The float64 parameters as the uint32 words the programs take."""
    return np.array([values[k] for k in PARAMS], np.float64).view(np.uint32)


def _params(words: jnp.ndarray) -> dict[str, jnp.ndarray]:
    v = lax.bitcast_convert_type(words.reshape(len(PARAMS), 2), jnp.float64)
    return {k: v[i] for i, k in enumerate(PARAMS)}


def _near_int(x: jnp.ndarray, tol: float) -> jnp.ndarray:
    return jnp.abs(x - jnp.round(x)) <= tol


def low_stretch(a: jnp.ndarray, b: jnp.ndarray, r: jnp.ndarray, p: dict) -> tuple:
    """Each capsule's low stretch, elementwise over items.

    Args:
      a, b: (..., 3) float64 capsule axis ends (world).
      r: (...) float64 radii.
    Returns (low, pa, pb, k, borderline): whether the capsule is low, the stretch's ends
    (..., 2), its samples k (int32), and whether a decision is within its tolerance."""
    za = a[..., 2] - p["table_z"] - r
    zb = b[..., 2] - p["table_z"] - r
    zlo = jnp.minimum(za, zb)
    low = zlo <= p["height"]
    dz = zb - za
    steep = jnp.abs(dz) > DZ_MIN
    t_h = jnp.where(steep, (p["height"] - za) / jnp.where(steep, dz, 1.0), 0.0)
    t0 = jnp.where(za <= p["height"], 0.0, jnp.clip(t_h, 0.0, 1.0))
    t1 = jnp.where(zb <= p["height"], 1.0, jnp.clip(t_h, 0.0, 1.0))
    d = b[..., :2] - a[..., :2]
    pa = a[..., :2] + t0[..., None] * d
    pb = a[..., :2] + t1[..., None] * d
    e = pb - pa
    v = jnp.sqrt(e[..., 0] * e[..., 0] + e[..., 1] * e[..., 1]) / p["half"]
    flat = (t0 == t1) | ((d[..., 0] == 0) & (d[..., 1] == 0))  # length exactly 0 everywhere
    k = jnp.where(flat, 1, jnp.ceil(v).astype(jnp.int32) + 1)
    borderline = (jnp.abs(zlo - p["height"]) <= TOL_Z) | (~flat & _near_int(v, TOL_K))
    return low, pa, pb, k, borderline


def sample_cells(pt: jnp.ndarray, r: jnp.ndarray, reach: int, nx: int, ny: int, p: dict) -> tuple:
    """The cells around samples and which lie within the radius.

    Args:
      pt: (n, 2) float64 samples; r: (n,) float64 radii.
    Returns (cx, cy, hit, borderline): the m = 2R + 1 columns (n, m) and rows (n, m) of the
    cells tested around each sample, (n, m rows, m columns) whether each is on the grid and
    within r, and (n,) whether a decision of the sample's is within its tolerance.  The cells
    are those around the sample's, but the columns of a sample off the grid's sides are
    those at its nearest side: they hold every cell of the grid within R columns of it (and
    more, which lie farther than r)."""
    d = np.arange(-reach, reach + 1, dtype=np.int32)
    lo = jnp.stack([p["x0"], p["y0"]])
    u = (pt - lo) / p["cell"]  # (n, 2)
    ixy = jnp.floor(u).astype(jnp.int32)
    cx = jnp.clip(ixy[:, 0], 0, nx - 1)[:, None] + d[None]  # (n, m)
    cy = ixy[:, 1, None] + d[None]

    def gap(x: jnp.ndarray, c: jnp.ndarray, x0: jnp.ndarray) -> jnp.ndarray:  # distance to the cells' squares
        return jnp.maximum(jnp.abs(x[:, None] - (x0 + (c + 0.5) * p["cell"])) - p["half"], 0.0)

    gx, gy = gap(pt[:, 0], cx, p["x0"]), gap(pt[:, 1], cy, p["y0"])
    s = (gy * gy)[:, :, None] + (gx * gx)[:, None, :]  # (n, m, m): gx * gx + gy * gy
    r2 = (r * r)[:, None, None]
    on_grid = ((cy >= 0) & (cy < ny))[:, :, None] & ((cx >= 0) & (cx < nx))[:, None, :]
    hit = on_grid & (s <= r2)
    near = on_grid & (jnp.abs(s - r2) <= TOL_S)
    borderline = jnp.any(_near_int(u, TOL_U), axis=1) | jnp.any(near, axis=(1, 2))
    return cx, cy, hit, borderline


def index_pass(
    shape: IndexShape,
    marks: jnp.ndarray,
    a: jnp.ndarray,
    b: jnp.ndarray,
    ints: jnp.ndarray,
    starts: jnp.ndarray,
    words: jnp.ndarray,
) -> PassOut:
    """Mark the cells of one window of a block's items.

    Args:
      marks: (size,) int32 marks of the edge group (`IndexShape.size`).
      a, b: (states, nc, 3) float32 capsule ends of the block's states (padding after n).
      ints: (5,) int32: the block's first state s0 (numbered within the batch), its states n,
        the window's first candidate rank, the group's states [lo, hi).
      starts: (edges + 1,) int32 the first state of each edge of the group, and the end,
        padded with int32 max.
      words: the float64 parameters (`params_words`).
    """
    p = _params(words)
    s0, n, off, g_lo, g_hi = ints[0], ints[1], ints[2], ints[3], ints[4]
    nt = len(shape.caps)
    caps = np.asarray(shape.caps)
    radii = np.asarray(shape.radii, np.float64)
    at = a[:, caps].astype(jnp.float64)  # (S, nt, 3)
    bt = b[:, caps].astype(jnp.float64)
    state = jnp.arange(shape.states, dtype=jnp.int32)
    s = s0 + state
    in_block = state < n
    in_group = in_block & (s >= g_lo) & (s < g_hi)
    edge = (jnp.searchsorted(starts, s, side="right", method="scan_unrolled") - 1).astype(jnp.int32)
    za = at[..., 2] - p["table_z"] - radii
    zb = bt[..., 2] - p["table_z"] - radii
    zlo = jnp.minimum(za, zb)
    low_caps = jnp.any(in_block[:, None] & (zlo <= p["height"]), axis=0)
    # candidates of the group's states, compacted: the window [off, off + items) by rank
    cand = (in_group[:, None] & (zlo <= p["height"] + TOL_Z)).reshape(-1)
    rank = jnp.cumsum(cand, dtype=jnp.int32) - 1
    slot = rank - off
    take = cand & (slot >= 0) & (slot < shape.items)
    ids = (
        jnp.full(shape.items, -1, jnp.int32)
        .at[jnp.where(take, slot, shape.items)]
        .set(jnp.arange(cand.shape[0], dtype=jnp.int32), mode="drop")
    )
    n_cand = jnp.sum(cand, dtype=jnp.int32)
    n_window = jnp.clip(n_cand - off, 0, shape.items)
    used = jnp.arange(shape.items, dtype=jnp.int32) < n_window
    safe = jnp.maximum(ids, 0)
    i_state, i_cap = safe // nt, safe % nt
    r_item = jnp.asarray(radii)[i_cap]
    low, pa, pb, k, item_border = low_stretch(at[i_state, i_cap], bt[i_state, i_cap], r_item, p)
    # the samples of the items that fit, in slots
    k_eff = jnp.where(used & low & ~item_border, k, 0)
    cum = jnp.cumsum(k_eff, dtype=jnp.int32)
    fits = jnp.sum(cum <= shape.samples, dtype=jnp.int32)
    n_done = jnp.minimum(n_window, fits)
    done = jnp.arange(shape.items, dtype=jnp.int32) < n_done
    total = jnp.where(n_done > 0, cum[jnp.maximum(n_done - 1, 0)], 0)
    slots = jnp.arange(shape.samples, dtype=jnp.int32)
    owner = jnp.minimum(jnp.searchsorted(cum, slots, side="right", method="scan_unrolled"), shape.items - 1).astype(
        jnp.int32
    )
    sampled = slots < total
    j = slots - (cum[owner] - k_eff[owner])
    frac = j.astype(jnp.float64) / jnp.maximum(k[owner] - 1, 1).astype(jnp.float64)
    pa_o, pb_o = pa[owner], pb[owner]
    pt = pa_o + frac[:, None] * (pb_o - pa_o)
    cx, cy, hit, sample_border = sample_cells(pt, r_item[owner], shape.reach, shape.nx, shape.ny, p)
    border = item_border | jnp.zeros(shape.items, bool).at[owner].max(sampled & sample_border)
    border = border & done
    # the marks of the items that are not borderline: each sample's rows, a window of columns
    # each (rows off the grid, and samples that mark nothing, at a valid place, marking 0)
    keep = sampled & ~border[owner]
    e = jnp.clip(edge[i_state][owner], 0, shape.edges - 1)
    row = jnp.clip(cy, 0, shape.ny - 1)
    start = (e[:, None] * shape.ny + row) * shape.width + cx[:, :1] + shape.reach  # (n, m) window starts
    values = (keep[:, None, None] & hit).astype(jnp.int32)
    dims = lax.ScatterDimensionNumbers(
        update_window_dims=(2,), inserted_window_dims=(), scatter_dims_to_operand_dims=(0,)
    )
    marks = lax.scatter_max(marks, start[..., None], values, dims, mode="promise_in_bounds")
    # borderline items, for the host
    frank = jnp.cumsum(border, dtype=jnp.int32) - 1
    fslot = jnp.where(border & (frank < shape.flags), frank, shape.flags)
    flag_ids = jnp.full(shape.flags, -1, jnp.int32).at[fslot].set(ids, mode="drop")
    fsafe = jnp.maximum(flag_ids, 0)
    ends = jnp.concatenate([a[:, caps].reshape(-1, 3)[fsafe], b[:, caps].reshape(-1, 3)[fsafe]], axis=1)
    counts = jnp.stack([n_cand, off + n_done, jnp.sum(border, dtype=jnp.int32), total])
    return PassOut(marks, counts, low_caps, flag_ids, ends)


def mark_cells(shape: IndexShape, marks: jnp.ndarray, edge: jnp.ndarray, cell: jnp.ndarray) -> jnp.ndarray:
    """Set the marks of pairs (edge, cell iy * nx + ix) (an edge of -1: none)."""
    cy, cx = cell // shape.nx, cell % shape.nx
    where = (edge * shape.ny + cy) * shape.width + cx + shape.reach
    return marks.at[jnp.where(edge >= 0, where, shape.size)].max(1, mode="drop")


def extract_pairs(shape: IndexShape, marks: jnp.ndarray, off: jnp.ndarray, capacity: int, blocks: int) -> Window:
    """The marked pairs of ranks [off, off + capacity) in (cell, edge) order: their edges in
    `blocks` equal blocks (-1 past the last pair), and the number of edges of every cell.

    The marks are packed into words of 32 edges of a cell; each pair is found from its rank
    (the word holding it by a binary search over the words' running counts, then the bit),
    so the work is one pass over the marks and a few steps per pair: no scatter."""
    g, c = shape.edges, shape.cells
    w = g // 32
    grid = marks.reshape(g, shape.ny, shape.width)[:, :, shape.reach : shape.reach + shape.nx]
    bits = (grid > 0).reshape(w, 32, c).astype(jnp.uint32)
    shift = jnp.arange(32, dtype=jnp.uint32)
    words = jnp.sum(bits << shift[None, :, None], axis=1, dtype=jnp.uint32).T.reshape(-1)  # (cells * w,)
    pop = lax.population_count(words).astype(jnp.int32)
    counts = jnp.sum(pop.reshape(c, w), axis=1, dtype=jnp.int32)
    cum = jnp.cumsum(pop, dtype=jnp.int32)  # pairs up to each word, inclusive
    rank = off + jnp.arange(capacity, dtype=jnp.int32)
    i = jnp.minimum(jnp.searchsorted(cum, rank, side="right", method="scan_unrolled"), c * w - 1).astype(jnp.int32)
    word = words[i]
    within = rank - (cum[i] - pop[i])  # the pair is the word's (within + 1)-th set bit
    prefix = jnp.asarray(np.array([(2 << m) - 1 for m in range(32)], np.uint64).astype(np.uint32))  # bits 0..m
    bit = jnp.zeros(capacity, jnp.int32)  # the set bits below it number `within`: a binary search
    for step in (16, 8, 4, 2, 1):
        below = lax.population_count(word & prefix[bit + step - 1]).astype(jnp.int32) <= within
        bit = jnp.where(below, bit + step, bit)
    edge = (i % w) * 32 + bit
    out = jnp.where(rank < cum[-1], edge, -1)
    size = capacity // blocks
    return Window(counts, tuple(out[k * size : (k + 1) * size] for k in range(blocks)))


def empty_marks(shape: IndexShape) -> jnp.ndarray:
    return jnp.zeros(shape.size, jnp.int32)
