"""Where on the table the map can push the target toward its goal: a cost for Greedy's score.

Greedy scores a candidate by the target's path length to the goal (`GoalField`).  Behind
the tunnel's wall that score is blind to where the arm can act: a push that leaves the
target beside the opening's far edge looks as good as one that leaves it in front of the
opening, although from the first no edge of the map pushes it on.  `push_pairs` finds,
for every reach cell, the edges of the map that can push a target there toward the goal:
their start is clear of the scene's fixed obstacles (by `FIXED_MARGIN`), and before their
first state within that margin (the cut `actions.cut_at_fixed` makes; an edge left with
fewer than MIN_EDGE_STATES states is never offered, nor counted) one of the arm's
table-checked capsules passes low over the cell (its lower end at most `height` above the
table) moving within `max_angle` of the goal field's descent (`push_counts`: how many per
cell).  `push_weights` turns the counts into a cost multiplier per point of the table (1
where pushes toward the goal are as common as on the median cell, more where rarer), and
`GoalField(weights=...)` integrates it along the path: the score becomes the cost of the
cheapest way to the goal through places the map can push from.

The counts take minutes for a map of 1,000,000 edges on a CPU: `cached_counts` keeps
them in lmjx's cache folder (`lmjx.runtime.cache`, `<dir>/pushes`), keyed by what they are computed
from (the robot's model, the edges' starts, twists and durations, the reach grid, the
scenario, the settings below, JAX's platform), so a map and scenario pay them once.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy import ndimage

from lmjx.edges.bundle import Bundle
from lmjx.edges.index import capsule_ends_kernel
from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.planner.clearance import EDGE_BOXES, FIXED_MARGIN, MIN_EDGE_STATES, box_kernel, cut_at_fixed
from lmjx.planner.goalfield import GoalField
from lmjx.planner.transit import TransitPlanner
from lmjx.reach.reachability import ReachResult
from lmjx.runtime.batching import backend
from lmjx.runtime.cache import cache_dir
from lmjx.runtime.fileio import atomic_path
from lmjx.runtime.progress import Progress
from lmjx.sim.scenarios import Scenario

MAX_ANGLE = 45.0  # [deg] a capsule's motion counts as toward the goal within this of the field's descent
HEIGHT = 0.05  # [m] ... when its lower end is at most this above the table
STATES_PER_CALL = 200_000  # edge states read and checked per pass
COUNTS_VERSION = 2  # what the cached counts mean (2: edges cut at the wall as actions are)
MEMO_ATTR = "_push_memo"  # kept on the bundle: (what, scenario, settings) -> what was computed for it


def far_objects(sc: Scenario) -> np.ndarray:
    """Poses (n, 7) that put the scenario's movable objects out of the arm's way (the counts
    depend on the fixed obstacles only)."""
    objs = np.zeros((len(sc.movable), 7))
    objs[:, 0] = 10.0 + 2.0 * np.arange(len(objs))
    objs[:, 2] = 10.0
    objs[:, 3] = 1.0
    return objs


def push_pairs(
    robot: Robot,
    failure: Failure,
    bundle: Bundle,
    reach: ReachResult,
    sc: Scenario,
    field: GoalField,
    max_angle: float = MAX_ANGLE,
    height: float = HEIGHT,
    progress: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """(cell, edge) pairs, unique, cells numbered iy * nx + ix: the edges that push toward the
    goal over each reach cell (module docstring).  A capsule's motion is that of its lower
    end from one state to the next.  `progress`: a bar (or lines) on stderr, per edge."""
    tp = TransitPlanner(robot, failure, batched=True)
    tp.set_scene(sc, far_objects(sc), acting=False)
    fixed = np.nonzero(~tp.scene.movable)[0]
    ny, nx = reach.labels.shape
    found: list[np.ndarray] = []
    if not len(fixed):
        starts_clear = np.ones(bundle.n_edges, bool)
    else:
        starts_clear = tp.scene_slacks(np.asarray(bundle.q_start, np.float64))[:, fixed].min(axis=1) >= 0
    edges = np.nonzero(starts_clear)[0]
    arm = robot.arm
    caps = np.asarray(arm.table_caps)
    r_cap = np.asarray(arm.cap_r, np.float64)[caps]
    ends_kernel = capsule_ends_kernel(robot)
    boxes = box_kernel(robot, tp.scene.padded(EDGE_BOXES, fixed)) if len(fixed) else None
    gy, gx = np.gradient(field.values, field.cell)  # the descent is minus this
    cos_min = math.cos(math.radians(max_angle))
    cell = reach.config.cell
    x0, y0 = reach.xs[0] - cell / 2, reach.ys[0] - cell / 2
    width = bundle.n_edges
    lengths = np.asarray(bundle.length, np.int64)
    offsets = np.asarray(bundle.offset, np.int64)
    bar = Progress(total=len(edges), desc=f"push counts, scenario {sc.number}", enabled=progress, unit="edge")
    i = 0
    while i < len(edges):
        # a run of edges whose states (contiguous in the file) make one pass
        j, n = i, 0
        while j < len(edges) and (n == 0 or n + lengths[edges[j]] <= STATES_PER_CALL):
            n += int(lengths[edges[j]])
            j += 1
        es = edges[i:j]
        i = j
        bar.update(len(es))
        lo, hi = int(offsets[es[0]]), int(offsets[es[-1]] + lengths[es[-1]])
        block = np.asarray(bundle.q[lo:hi], np.float32)
        rows = np.concatenate([np.arange(offsets[e], offsets[e] + lengths[e]) for e in es]) - lo
        q = block[rows]
        lens = lengths[es]
        owner = np.repeat(np.arange(len(es)), lens)
        k = np.arange(len(owner)) - np.concatenate([[0], np.cumsum(lens)[:-1]])[owner]
        clearance = None if boxes is None else boxes.run(q)["box_clearance"][:, : len(fixed)].min(axis=1)
        prefix = cut_at_fixed(clearance, owner, k, lens)
        prefix[prefix < MIN_EDGE_STATES] = 0  # such an edge is never offered (`edge_prefixes`)
        ends = ends_kernel.run(q)
        a = ends["a"][:, caps].astype(np.float64)
        b = ends["b"][:, caps].astype(np.float64)
        low = np.where((a[..., 2] <= b[..., 2])[..., None], a, b)  # (m, nc, 3)
        z = low[..., 2] - arm.table_z - r_cap[None]
        moving = k + 1 < prefix[owner]  # this state and the next are executed
        row, cap = np.nonzero((z <= height) & moving[:, None])
        if not len(row):
            continue
        p = low[row, cap, :2]
        v = low[row + 1, cap, :2] - p
        fx = np.clip(np.floor((p[:, 0] - field.lo[0]) / field.cell).astype(np.int64), 0, field.shape[1] - 1)
        fy = np.clip(np.floor((p[:, 1] - field.lo[1]) / field.cell).astype(np.int64), 0, field.shape[0] - 1)
        g = -np.stack([gx[fy, fx], gy[fy, fx]], axis=1)
        speed, gn = np.hypot(v[:, 0], v[:, 1]), np.hypot(g[:, 0], g[:, 1])
        toward = ((v * g).sum(axis=1) >= cos_min * speed * gn) & (speed > 1e-4) & (gn > 0)
        cx = np.floor((p[toward, 0] - x0) / cell).astype(np.int64)
        cy = np.floor((p[toward, 1] - y0) / cell).astype(np.int64)
        inside = (cx >= 0) & (cx < nx) & (cy >= 0) & (cy < ny)
        e = es[owner[row[toward]]][inside]
        found.append(np.unique((cy[inside] * nx + cx[inside]) * width + e))  # each edge once per cell
    bar.close()
    pairs = np.unique(np.concatenate(found)) if found else np.zeros(0, np.int64)
    return pairs // width, pairs % width


def push_counts(cells: np.ndarray, reach: ReachResult) -> np.ndarray:
    """(ny, nx) the pairs per reach cell: how many edges push toward the goal there."""
    ny, nx = reach.labels.shape
    return np.bincount(cells, minlength=ny * nx).reshape(ny, nx)


def counts_key(robot: Robot, bundle: Bundle, reach: ReachResult, sc: Scenario, field: GoalField) -> str:
    """What the push counts of this map and scenario are computed from (`push_pairs` with its
    default MAX_ANGLE and HEIGHT), hashed: the cache's file name (`cached_counts`)."""
    how = {k: v for k, v in dataclasses.asdict(bundle.config).items() if k not in ("chunk", "build_chunk")}
    h = hashlib.sha256()
    for text in (
        f"v{COUNTS_VERSION} {FIXED_MARGIN} {MIN_EDGE_STATES} {MAX_ANGLE} {HEIGHT} {backend()}",
        robot.model_hash,
        repr(sorted(how.items())),
        repr(sc),
        repr(reach.config.cell),
    ):
        h.update(text.encode())
        h.update(b"\0")
    arrays = (reach.xs, reach.ys, field.values, np.asarray(field.lo), np.asarray(field.cell))
    for a in (*arrays, bundle.length, bundle.q_start, bundle.twist, bundle.duration, bundle.site):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:40]


def cached_counts(key: str, shape: tuple, compute: Callable[[], np.ndarray]) -> tuple[np.ndarray, Path | None]:
    """The push counts filed under `key` (`counts_key`) in lmjx's cache folder, or `compute()`
    written there atomically (the cache turned off: computed every time); also the file
    (None without one).  A file that cannot be read, or not counts of `shape`, is computed
    again."""
    folder = cache_dir()
    path = None if folder is None else folder / "pushes" / f"{key}.npy"
    if path is not None and path.exists():
        try:
            counts = np.load(path, allow_pickle=False)
            if counts.shape == tuple(shape) and counts.dtype.kind in "iu":
                return counts, path
        except (OSError, ValueError):
            pass
    counts = compute()
    if path is not None:
        try:
            with atomic_path(path) as tmp, open(tmp, "wb") as f:
                np.save(f, counts, allow_pickle=False)
        except OSError:
            return counts, None  # a folder that cannot be written: computed, not kept
    return counts, path


def bundle_memo(bundle: Bundle) -> dict:
    """What was computed from this bundle's edges (the weighted fields): it lives as long as
    the bundle."""
    memo = getattr(bundle, MEMO_ATTR, None)
    if memo is None:
        memo = {}
        setattr(bundle, MEMO_ATTR, memo)
    return memo


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
