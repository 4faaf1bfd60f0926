"""Where on the table the map can push the target toward a scenario's goal: push counts per
reach cell (Greedy's cost of a path weighs them: `lmjx.planner.pushfield`).

`push_pairs` finds, for every reach cell, the edges of the map that can push a target there
toward the goal (the path field around the fixed obstacles, `GoalField`): their start is
clear of the scene's fixed obstacles (by `FIXED_MARGIN`), and before their first state
within that margin (the cut `sceneboxes.cut_at_fixed` makes; an edge left with fewer than
MIN_EDGE_STATES states is never offered, nor counted) one of the arm's table-checked
capsules passes low over the cell (its lower end at most `height` above the table) moving
within `max_angle` of the goal field's descent (`push_counts`: how many per cell).

The pairs come in two stages.  The map's part, the same for every scenario, is found once
per bundle (`pushsamples.push_samples`: every state and capsule low over a reach cell, with
its next state; on JAX's device, only those coming back).  A scenario's part is a pass over
those samples (`_group_hits`): the direction test against the scenario's goal field, and,
where the scenario has fixed obstacles, the start check and the cut, both only for the edges
with a sample toward the goal and only on their states up to that sample's next one.

Where the counts come from (`_score_field` in `lmjx.planner.scoring`): the map itself,
which holds those of the robot's built-in scenarios and both task sets (`builtin_counts`,
computed when the map is built and stored in `/edges/push`, used where the key
`counts_key` matches, JAX's platform included); else lmjx's cache folder
(`lmjx.runtime.cache`, `<dir>/pushes`: `cached_counts`); else they are computed here and
kept there, so a map and scenario pay them once.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from lmjx.mapfile.bundle import Bundle
from lmjx.mapfile.pushsamples import PushSamples, push_samples
from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.reach.reachability import ReachResult
from lmjx.runtime.batching import backend
from lmjx.runtime.cache import cache_dir
from lmjx.runtime.cores import usable_cores
from lmjx.runtime.fileio import atomic_path
from lmjx.sim.goalfield import GoalField
from lmjx.sim.scenarios import SCENARIOS, TASK_SETS, Scenario, scenario
from lmjx.sim.sceneboxes import (
    EDGE_BOXES,
    FIXED_MARGIN,
    MIN_EDGE_STATES,
    SceneClearance,
    box_kernel,
    cut_at_fixed,
    scene_boxes,
)

MAX_ANGLE = 45.0  # [deg] a capsule's motion counts as toward the goal within this of the field's descent
HEIGHT = 0.05  # [m] ... when its lower end is at most this above the table
COUNTS_VERSION = 2  # what the counts mean (2: edges cut at the wall as actions are)
MEMO_ATTR = "_push_memo"  # kept on the bundle: (what, scenario, settings) -> what was computed for it
PARALLEL_SAMPLES = 1 << 18  # samples from which a scenario's direction test runs on all cores
READ_ROWS = 1 << 20  # edge states read at a time from a lazily opened map (the cut at a wall)


@dataclasses.dataclass(frozen=True)
class StoredCounts:
    """The push counts of one scenario, as a map stores them (`/edges/push`)."""

    key: str  # `counts_key`
    scenario: int
    tasks: str
    counts: np.ndarray  # (ny, nx) int32


def scenario_field(robot: Robot, sc: Scenario) -> GoalField:
    """The scenario's goal field over the robot's table, unweighted: what the counts are
    computed against (`lmjx.planner.scoring` builds the same)."""
    arm = robot.arm
    lo, hi = arm.table_center[:2] - arm.table_half[:2], arm.table_center[:2] + arm.table_half[:2]
    return GoalField(sc, lo, hi)


def builtin_counts(
    robot: Robot, failure: Failure, bundle: Bundle, reach: ReachResult, progress: bool = False
) -> list[StoredCounts]:
    """The push counts of the robot's built-in scenarios (1, 2, 3), each task set: what a
    map stores when it is built (the map's samples found once for all of them)."""
    out = []
    for tasks in TASK_SETS:
        for number in sorted(SCENARIOS):
            sc = scenario(number, robot.profile.task_scale, tasks)
            field = scenario_field(robot, sc)
            counts = scenario_counts(robot, failure, bundle, reach, sc, field, progress)
            out.append(StoredCounts(counts_key(robot, bundle, reach, sc, field), number, tasks, counts))
    return out


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
    """(cell, edge) pairs, unique, sorted by cell then edge, cells numbered iy * nx + ix: the
    edges that push toward the goal over each reach cell (module docstring).  A capsule's
    motion is that of its lower end from one state to the next.  `progress`: a bar (or lines)
    on stderr while the map's push samples are found."""
    samples = bundle_samples(robot, bundle, reach, height, progress)
    hit = _group_hits(samples, robot, failure, bundle, sc, field, max_angle)
    cells, edges = samples.group_cell[hit].astype(np.int64), samples.group_edge[hit].astype(np.int64)
    order = np.lexsort((edges, cells))
    return cells[order], edges[order]


def scenario_counts(
    robot: Robot,
    failure: Failure,
    bundle: Bundle,
    reach: ReachResult,
    sc: Scenario,
    field: GoalField,
    progress: bool = False,
) -> np.ndarray:
    """(ny, nx) int32 the push counts of the scenario (`push_counts` of `push_pairs`, with
    the default MAX_ANGLE and HEIGHT), without sorting the pairs."""
    samples = bundle_samples(robot, bundle, reach, HEIGHT, progress)
    hit = _group_hits(samples, robot, failure, bundle, sc, field, MAX_ANGLE)
    ny, nx = reach.labels.shape
    return np.bincount(samples.group_cell[hit], minlength=ny * nx).astype(np.int32).reshape(ny, nx)


def counts_for(
    robot: Robot, failure: Failure, bundle: Bundle, reach: ReachResult, sc: Scenario, field: GoalField
) -> tuple[np.ndarray, str]:
    """The scenario's push counts (`field`: its unweighted goal field) and where they came
    from: "map" (stored when the map was built, under the same key), "cache" (lmjx's cache
    folder), or "computed" (then kept in the cache folder)."""
    key = counts_key(robot, bundle, reach, sc, field)
    stored = bundle.push.get(key)
    if stored is not None and stored.shape == reach.labels.shape:
        return stored, "map"
    computed: list[bool] = []

    def compute() -> np.ndarray:
        computed.append(True)
        return scenario_counts(robot, failure, bundle, reach, sc, field, progress=True)

    counts, _ = cached_counts(key, reach.labels.shape, compute)
    return counts, "computed" if computed else "cache"


def bundle_samples(robot: Robot, bundle: Bundle, reach: ReachResult, height: float, progress: bool) -> PushSamples:
    """The map's push samples (`pushsamples.push_samples`), found once per bundle, height
    and reach grid."""
    memo = bundle_memo(bundle)
    key = ("push samples", robot.model_hash, height, reach.config.cell, float(reach.xs[0]), float(reach.ys[0]),
           reach.labels.shape)  # fmt: skip
    if key not in memo:
        memo[key] = push_samples(robot, bundle, reach, height, progress)
    return memo[key]


@dataclasses.dataclass
class FixedCut:
    """A scenario's fixed obstacles as `_prefixes` checks edges against them: the scene's
    checks (the start check, as the planner's) and the box-clearance program of its fixed
    boxes, made once per scenario and shared by the threads that count chunks of a build (one
    at a time: the checks keep state)."""

    checks: SceneClearance  # against the scene (the start check)
    fixed: np.ndarray  # the scene's fixed boxes
    boxes: Any  # `sceneboxes.box_kernel` of them
    lock: threading.Lock = dataclasses.field(default_factory=threading.Lock)


def fixed_cut(robot: Robot, sc: Scenario) -> FixedCut | None:
    """The scenario's `FixedCut`; None for a scenario without fixed obstacles."""
    if not sc.fixed:
        return None
    checks = SceneClearance(robot, batched=True)
    checks.place(scene_boxes(sc, far_objects(sc)))
    assert checks.scene is not None
    fixed = np.nonzero(~checks.scene.movable)[0]
    return FixedCut(checks, fixed, box_kernel(robot, checks.scene.padded(EDGE_BOXES, fixed)))


def _group_hits(
    s: PushSamples,
    robot: Robot,
    failure: Failure,
    bundle: Bundle,
    sc: Scenario,
    field: GoalField,
    max_angle: float,
    cut: FixedCut | None = None,
    threads: int | None = None,
) -> np.ndarray:
    """(G,) whether each (edge, cell) group of samples holds one that pushes toward the
    goal before the edge's cut at a fixed obstacle, its start clear of them (`cut`: the
    scenario's `fixed_cut`, made here when not given; `threads`: the direction test's,
    default all cores)."""
    if not len(s):
        return np.zeros(0, bool)
    ok = _toward(s, field, max_angle, threads)
    if sc.fixed:
        edge = s.sample_edge()
        prefix = _prefixes(s, edge, ok, bundle, cut or fixed_cut(robot, sc))
        ok &= s.k + 1 < prefix[edge]
    return np.logical_or.reduceat(ok, s.group_start)


def _toward(s: PushSamples, field: GoalField, max_angle: float, threads: int | None = None) -> np.ndarray:
    """(n,) whether each sample's motion (`PushSamples.motion`, shared by the scenarios)
    lies within `max_angle` of the field's descent (its gradient by central differences, at
    the field cell under the sample), in parts on `threads` cores (default all: numpy's
    loops leave the interpreter lock)."""
    gy, gx = np.gradient(field.values, field.cell)
    g0, g1 = (-gx).ravel(), (-gy).ravel()  # the descent
    gn = np.hypot(g0, g1)
    cos_min = math.cos(math.radians(max_angle))
    cell = s.field_index(field.lo, field.cell, field.shape)
    v0, v1, speed = s.motion()
    out = np.empty(len(s), bool)

    def part(a: int, b: int) -> None:
        fc = cell[a:b]
        n = gn[fc]
        out[a:b] = (v0[a:b] * g0[fc] + v1[a:b] * g1[fc] >= cos_min * speed[a:b] * n) & (n > 0)

    threads = threads or usable_cores()
    cuts = np.linspace(0, len(s), threads + 1).astype(np.int64)
    if threads == 1 or len(s) < PARALLEL_SAMPLES:
        part(0, len(s))
    else:
        with ThreadPoolExecutor(threads, thread_name_prefix="lmjx-push") as pool:
            list(pool.map(part, cuts[:-1], cuts[1:]))
    return out


def _prefixes(s: PushSamples, edge: np.ndarray, ok: np.ndarray, bundle: Bundle, cut: FixedCut) -> np.ndarray:
    """(E,) how many states of each edge an action executes in the scenario, for the edges
    with a sample that passes `ok` (0 for the others): those before its first state within
    FIXED_MARGIN of a fixed obstacle (`cut_at_fixed`), 0 where that leaves fewer than
    MIN_EDGE_STATES or the edge starts within the margin.  Only the states up to the last
    passing sample's next one (or MIN_EDGE_STATES, to tell an edge cut shorter than that)
    are checked: a cut further on does not change which samples count."""
    lengths = np.asarray(bundle.length, np.int64)
    offsets = np.asarray(bundle.offset, np.int64)
    prefix = np.zeros(len(lengths), np.int64)
    first = np.nonzero(np.diff(edge, prepend=-1))[0]  # each edge's first sample (sorted by edge)
    kmax = np.full(len(lengths), -1, np.int64)
    kmax[edge[first]] = np.maximum.reduceat(np.where(ok, s.k, -1), first)
    cand = np.nonzero(kmax >= 0)[0]
    if not len(cand):
        return prefix
    fixed = cut.fixed
    with cut.lock:
        slacks = cut.checks.scene_slacks(np.asarray(bundle.q_start[cand], np.float64))
    cand = cand[slacks[:, fixed].min(axis=1) >= 0]
    need = np.minimum(np.maximum(kmax[cand] + 2, MIN_EDGE_STATES), lengths[cand])
    owner = np.repeat(np.arange(len(cand)), need)
    k = np.arange(len(owner)) - np.repeat(np.cumsum(need) - need, need)
    q = _state_rows(bundle, offsets[cand][owner] + k)
    with cut.lock:
        clearance = cut.boxes.run(q)["box_clearance"][:, : len(fixed)].min(axis=1)
    cut = cut_at_fixed(clearance, owner, k, lengths[cand])
    cut[cut < MIN_EDGE_STATES] = 0  # such an edge is never offered (`edge_prefixes`)
    prefix[cand] = cut
    return prefix


def _state_rows(bundle: Bundle, rows: np.ndarray) -> np.ndarray:
    """(len(rows), nq) float32 the bundle's states `rows` (ascending): indexed in memory, or,
    from a lazily opened map, read in blocks of at most READ_ROWS consecutive rows."""
    if isinstance(bundle.q, np.ndarray):
        return np.asarray(bundle.q[rows], np.float32)
    out = np.empty((len(rows), bundle.q.shape[1]), np.float32)
    i = 0
    while i < len(rows):
        lo = int(rows[i])
        j = int(np.searchsorted(rows, lo + READ_ROWS))
        out[i:j] = np.asarray(bundle.q[lo : int(rows[j - 1]) + 1])[rows[i:j] - lo]
        i = j
    return out


def push_counts(cells: np.ndarray, reach: ReachResult) -> np.ndarray:
    """(ny, nx) the pairs per reach cell: how many edges push toward the goal there."""
    ny, nx = reach.labels.shape
    return np.bincount(cells, minlength=ny * nx).reshape(ny, nx)


def counts_key(robot: Robot, bundle: Bundle, reach: ReachResult, sc: Scenario, field: GoalField) -> str:
    """What the push counts of this map and scenario are computed from (`push_pairs` with its
    default MAX_ANGLE and HEIGHT), hashed: the counts' name in the map (`/edges/push`) and
    the cache's file name (`cached_counts`)."""
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
