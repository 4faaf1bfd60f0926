"""The map's part of the push counts (`lmjx.mapfile.pushmap`): where each edge's capsules
pass low over a reach cell, found once per map, whatever the scenario.

A push sample is an edge's state k and one of the arm's table-checked capsules whose lower
axis end is at most `height` above the table there (its surface within `height` of the
table), with a next state to move to: the end's position at k (in a reach cell) and at k + 1
(its motion, faster than `MIN_MOTION` per state).  Which samples push toward the goal and
which edges are cut short by a wall depend on the scenario (`pushfield.push_pairs`); the
samples do not.

The capsule ends are computed on JAX's device (`kernels.push.low_samples`) in runs of whole
edges, and only the few pairs low over the table come back (compacted there to a fixed
budget per run, a run that passes more is split and computed again); the host then applies
the exact float64 tests of the height, the motion and the cell, and sorts each run's samples
by edge and cell, so that a scenario's pass reduces each (edge, cell) group without a sort.
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from lmjx.mapfile.bundle import Bundle
from lmjx.model.robot import Robot
from lmjx.reach.reachability import ReachResult
from lmjx.runtime.batching import backend, fetch
from lmjx.runtime.cores import usable_cores
from lmjx.runtime.progress import Progress
from lmjx.sim.sceneboxes import MIN_EDGE_STATES

if TYPE_CHECKING:
    import jax

MIN_MOTION = 1e-4  # [m] a capsule end moving less than this from one state to the next pushes nothing
Z_SLACK = 1e-5  # [m] the device's float32 height test lets through what lies this little above the limit
ROWS = {"cpu": 1 << 12}  # edge states per device call, by platform (accelerators: ROWS_ACCELERATOR)
ROWS_ACCELERATOR = 1 << 18
BUDGET_SHARE = 8  # a call returns at most 1 / BUDGET_SHARE of its (state, capsule) pairs (a few % pass)

_PROGRAMS: dict[tuple, object] = {}
_PROGRAMS_LOCK = threading.Lock()


@dataclass
class PushSamples:
    """A map's push samples, sorted by edge, then reach cell (iy * nx + ix): group g, the
    samples of edge group_edge[g] over cell group_cell[g], is rows group_start[g] ..
    group_start[g + 1] - 1 of k, p and p_next."""

    height: float  # [m] the height the samples were found with
    n_edges: int
    k: np.ndarray  # (n,) int32 the state in its edge
    p: np.ndarray  # (n, 2) float32 x, y of the capsule's lower end at state k [m]
    p_next: np.ndarray  # (n, 2) float32 ... at state k + 1 [m]
    group_start: np.ndarray  # (G,) int64
    group_edge: np.ndarray  # (G,) int32
    group_cell: np.ndarray  # (G,) int32
    runs: int = 0  # runs of edges the device took
    device_calls: int = 0  # its calls: a run over the budget took more
    _field_index: dict = field(default_factory=dict, repr=False)  # goal-field grid -> each sample's cell in it
    _motion: tuple | None = field(default=None, repr=False)  # `motion`'s arrays, once computed

    def __len__(self) -> int:
        return len(self.k)

    def sample_edge(self) -> np.ndarray:
        """(n,) each sample's edge."""
        return np.repeat(self.group_edge, np.diff(np.append(self.group_start, len(self.k))))

    def motion(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(v0, v1, speed), (n,) float64 each: every sample's motion from p to p_next and its
        length, computed once (each scenario's direction test reads them)."""
        if self._motion is None:
            p, pn = self.p.astype(np.float64), self.p_next.astype(np.float64)
            v0, v1 = pn[:, 0] - p[:, 0], pn[:, 1] - p[:, 1]
            self._motion = (v0, v1, np.hypot(v0, v1))
        return self._motion

    def field_index(self, lo: np.ndarray, cell: float, shape: tuple[int, int]) -> np.ndarray:
        """(n,) int64 each sample's cell iy * nx + ix in a goal field's grid (`GoalField`:
        corner `lo`, `cell`, `shape` (ny, nx)); points off the grid take the nearest cell."""
        key = (float(lo[0]), float(lo[1]), float(cell), tuple(shape))
        if key not in self._field_index:
            self._field_index.clear()  # (one grid at a time: the fields of a robot's scenarios share it)
            p = self.p.astype(np.float64)
            fx = np.clip(np.floor((p[:, 0] - lo[0]) / cell).astype(np.int64), 0, shape[1] - 1)
            fy = np.clip(np.floor((p[:, 1] - lo[1]) / cell).astype(np.int64), 0, shape[0] - 1)
            self._field_index[key] = fy * shape[1] + fx
        return self._field_index[key]


def _rows() -> int:
    return ROWS.get(backend(), ROWS_ACCELERATOR)


def _program(robot: Robot, rows: int, budget: int):
    """`kernels.push.low_samples` jitted for `robot` and runs of `rows` states (one per
    process, robot and size)."""
    import jax

    from kernels.push import low_samples

    key = (robot.model_hash, rows, budget)
    with _PROGRAMS_LOCK:
        if key not in _PROGRAMS:
            arm = robot.arm

            def run(q, has_next, z_max, span):
                return low_samples(arm, q, has_next, z_max, span, budget)

            _PROGRAMS[key] = jax.jit(run)
        return _PROGRAMS[key]


def compile_program(robot: Robot) -> None:
    """Compile the device program `push_samples` runs on this platform for `robot` (its
    first run compiles it otherwise)."""
    nt = len(robot.arm.table_caps)
    if nt:
        rows = _rows()
        program = _program(robot, rows, rows * nt // BUDGET_SHARE)
        zeros = (np.zeros((rows + 1, robot.nq), np.float32), np.zeros(rows, bool), np.zeros(nt, np.float32))
        fetch(list(program(*zeros, np.zeros(2, np.int32))))


def _runs(lengths: np.ndarray, rows: int) -> list[tuple[int, int]]:
    """Edges [e0, e1) of each run: whole edges, at most `rows` states (or one longer edge)."""
    ends = np.cumsum(lengths)
    out, e0 = [], 0
    while e0 < len(lengths):
        base = ends[e0 - 1] if e0 else 0
        e1 = max(e0 + 1, int(np.searchsorted(ends, base + rows, side="right")))
        out.append((e0, e1))
        e0 = e1
    return out


def push_samples(
    robot: Robot,
    bundle: Bundle,
    reach: ReachResult,
    height: float,
    progress: bool = False,
    workers: int | None = None,
    device: jax.Device | None = None,
) -> PushSamples:
    """The push samples (module docstring) of the bundle's edges that keep at least
    MIN_EDGE_STATES states, over the reach map's cells.  Runs of edges go through the device
    and the host's tests on `workers` threads (default `threads()`; each reads its run,
    launches it and takes its samples: numpy, the reads and JAX's calls leave the
    interpreter lock).  `progress`: a bar on stderr, per edge.  `device`: the JAX device the
    runs' program runs on (None: JAX's default), set in each worker thread (JAX's default
    device is a setting of the thread that enters it)."""
    lengths = np.asarray(bundle.length, np.int64)
    rows = max(_rows(), int(lengths.max(initial=1)))
    run = _Run(robot, bundle, reach, height, rows)
    bar = Progress(total=len(lengths), desc="push samples", enabled=progress, unit="edge")
    runs = _runs(lengths, rows) if run.nt and len(lengths) else []
    parts = []

    def call(r: tuple[int, int]) -> tuple:
        if device is None:
            return run(*r)
        import jax

        with jax.default_device(device):
            return run(*r)

    with ThreadPoolExecutor(workers or threads(), thread_name_prefix="lmjx-push") as pool:
        for part, (e0, e1) in zip(pool.map(call, runs), runs, strict=True):
            parts.append(part)
            bar.update(e1 - e0)
    bar.close()
    return _assemble(parts, height, len(lengths))


def threads() -> int:
    """Threads taking runs of edges (`push_samples`): the cores, up to 8."""
    return max(1, min(8, usable_cores()))


class _Run:
    """One run of whole edges: its states read, the device's low pairs, the host's tests."""

    def __init__(self, robot: Robot, bundle: Bundle, reach: ReachResult, height: float, rows: int) -> None:
        arm = robot.arm
        caps = np.asarray(arm.table_caps)
        self.nt = len(caps)
        self.r_cap = np.asarray(arm.cap_r, np.float64)[caps]
        self.table_z, self.height = arm.table_z, height
        self.z_max = (arm.table_z + self.r_cap + height + Z_SLACK).astype(np.float32)
        self.bundle, self.nq, self.rows = bundle, robot.nq, rows
        self.budget = rows * self.nt // BUDGET_SHARE  # (at least nt: a state's pairs always fit)
        self.lengths = np.asarray(bundle.length, np.int64)
        self.offsets = np.asarray(bundle.offset, np.int64)
        self.program = _program(robot, rows, self.budget) if self.nt else None
        ny, nx = reach.labels.shape
        cell = reach.config.cell
        self.grid = (reach.xs[0] - cell / 2, reach.ys[0] - cell / 2, cell, nx, ny)

    def __call__(self, e0: int, e1: int) -> tuple:
        lengths, offsets = self.lengths, self.offsets
        a, b = int(offsets[e0]), int(offsets[e1 - 1] + lengths[e1 - 1])
        n = b - a
        stop = min(b + 1, len(self.bundle.q))  # (the row after the run: read, never used)
        q = np.zeros((self.rows + 1, self.nq), np.float32)
        q[: stop - a] = self.bundle.q[a:stop]
        edge = np.repeat(np.arange(e0, e1), lengths[e0:e1])
        k = np.arange(n) - (offsets[edge] - a)
        has_next = np.zeros(self.rows, bool)
        has_next[:n] = (k + 1 < lengths[edge]) & (lengths[edge] >= MIN_EDGE_STATES)
        pieces = _split(self.program, q, has_next, self.z_max, 0, n, self.budget)
        index, low, next_xy = (np.concatenate(x) for x in zip(*pieces, strict=True))
        # (a run over the budget is computed again in halves: 2 x pieces - 1 calls)
        return (*self._host_pass(index, low, next_xy, edge, k, e0), 2 * len(pieces) - 1)

    def _host_pass(self, index, low, next_xy, edge, k, e0) -> tuple:
        """The run's samples: the exact tests (height, motion, cell) in float64, sorted by
        edge, then cell.  (k, p, p_next, edge, cell) back."""
        x0, y0, cell, nx, ny = self.grid
        state, cap = index // self.nt, index % self.nt
        z = low[:, 2].astype(np.float64) - self.table_z - self.r_cap[cap]
        p = low[:, :2].astype(np.float64)
        v = next_xy.astype(np.float64) - p
        cx = np.floor((p[:, 0] - x0) / cell).astype(np.int64)
        cy = np.floor((p[:, 1] - y0) / cell).astype(np.int64)
        keep = (z <= self.height) & (np.hypot(v[:, 0], v[:, 1]) > MIN_MOTION)
        keep &= (cx >= 0) & (cx < nx) & (cy >= 0) & (cy < ny)
        state = state[keep]
        c = cy[keep] * nx + cx[keep]
        e = edge[state]
        order = np.argsort((e - e0) * (nx * ny) + c, kind="stable")
        return (k[state][order].astype(np.int32), low[keep][order, :2], next_xy[keep][order],
                e[order].astype(np.int32), c[order].astype(np.int32))  # fmt: skip


def _split(program, q, has_next, z_max, lo: int, hi: int, budget: int) -> list[tuple]:
    """The low pairs of states [lo, hi) of a run, in calls each of which fits the budget
    (the run, else its halves, and so on: a state's pairs always fit)."""
    out = program(q, has_next, z_max, np.array([lo, hi], np.int32))
    count, index, low, next_xy = fetch(list(out))
    if int(count) <= budget:
        return [(index[: int(count)], low[: int(count)], next_xy[: int(count)])]
    mid = (lo + hi) // 2
    return _split(program, q, has_next, z_max, lo, mid, budget) + _split(program, q, has_next, z_max, mid, hi, budget)


def _assemble(parts: list[tuple], height: float, n_edges: int) -> PushSamples:
    calls = sum(part[-1] for part in parts)
    if parts:
        k, p, p_next, edge, c = (np.concatenate(x) for x in zip(*(part[:-1] for part in parts), strict=True))
    else:
        k, edge, c = (np.zeros(0, np.int32) for _ in range(3))
        p, p_next = np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32)
    new = np.ones(len(k), bool)
    new[1:] = (edge[1:] != edge[:-1]) | (c[1:] != c[:-1])
    start = np.nonzero(new)[0]
    p, p_next = np.ascontiguousarray(p), np.ascontiguousarray(p_next)
    return PushSamples(height, n_edges, k, p, p_next, start.astype(np.int64), edge[start], c[start], len(parts), calls)
