"""The map's spatial index: for each cell of the reach map, the edges during which the whole
arm (its table-checked capsules, swept over the edge's states) can touch an object there.

`arm_index_pairs` computes it on the device JAX uses (`ArmIndex`): the capsule ends by the
capsule program (`capsule_ends_kernel`, float32, launches of its own size), then passes of
the index kernel (`kernels.index`, float64) mark (edge, cell) pairs in a map of marks on the
device, and the pairs come back unique and sorted by (cell, edge).  Nothing on the host grows
with the states but the joint angles sent up: the borderline items the kernel hands back
(a decision within its tolerance of its threshold: none in most batches) are settled here
with the reference float64 arithmetic (`index_settle.settle_items`) and marked on the device
before the pairs are read.

The programs of one robot, reach grid and device (compiled once; the failure, the seed,
the edge count and the index height are inputs; sizes from `SIZES`):
  * the capsule ends: (C, 7) float32 -> (C, nc, 3) x 2, C = 32,768 on an accelerator, 1,024
    on a CPU (the planner's checks share it);
  * a pass: the ends of P = C x launches states (P = 32,768 on a GPU, 8,192 on a CPU) ->
    the (G x ny x (nx + 2R),) int32 marks (donated), through items x P candidate item
    slots and samples x P sample slots, each sample testing (2R + 1)^2 cells (R = ceil(the
    largest table radius / cell): 4 for the Panda on 2 cm cells); its counts, the capsules
    low in the block, up to `flags` borderline items;
  * marks: the marks and `marks` (edge, cell) pairs settled on the host -> the marks;
  * a window: the marks -> the edges of the pairs of ranks [off, off + out) in `out_blocks`
    blocks, and the pairs per cell (cells,);
  * empty marks.
G, the edges of one map of marks: 32,768 on a GPU, 4,096 on a CPU for the 60 x 50 cells of
2 cm (456 MB and 57 MB); a batch of more edges is indexed in groups of G, merged on the
host.  Work and memory per pass on a GPU: 0.8 M (state, capsule) z-tests, 98 k item slots,
328 k sample slots x 81 cells = 27 M float64 cell tests, 3 M windows of 9 marks written
(a scatter-max: only hits change a mark); 20 MB of capsule ends in.  A window reads the
marks once (6 M words of 32 edges) and finds each of its 4 M pairs by a binary search.  A
packing unit of case 2 (65,536 sampled edges, some 16,000 valid, 830 k states) takes 26
passes and one window; 1,000,000 edges about 390 passes (10 G cell tests) and 16 windows.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

from kernels.index import PARAMS, IndexShape, empty_marks, extract_pairs, index_pass, mark_cells, params_words
from lmjx.edges.index_settle import merge_groups, settle_items
from lmjx.model.robot import Robot
from lmjx.reach.reachability import ReachResult
from lmjx.runtime.batching import ChunkedKernel, backend
from lmjx.runtime.compiletime import compile_span, told_compiled
from lmjx.runtime.devices import index_devices, next_device

# The states whose largest low capsule sets how many cells around a sample the index looks
# at (the index's definition; only a borderline item can tell the difference).
NEIGHBOURHOOD_STATES = 1 << 16
INT32_MAX = np.iinfo(np.int32).max
_ENDS: dict[tuple, Any] = {}  # (model hash, chunk, device id) -> its capsule-ends program
_ENDS_LOCK = threading.Lock()


@dataclass(frozen=True)
class IndexSizes:
    """Launches per pass, capacities per state of a pass, marks and window sizes."""

    launches: int  # capsule launches per pass
    items: int  # candidate item slots per state
    samples: int  # sample slots per state
    marks_bytes: int  # a map of marks' size at most (edges x rows x columns, int32)
    edges: int  # edges per map of marks at most
    flags: int  # borderline items a pass reports (more: its block is settled on the host)
    marks: int  # host-settled marks per call
    out: int  # pairs per window
    out_blocks: int  # blocks a window's pairs come back in (only those holding pairs are copied)
    lag: int  # passes in flight before the oldest's counts are read


# Per state, a block of case 2 holds about 1.3 low capsules and 5.2 samples, of case 1 1.5
# and 8.1, with no failure 1.6 and 8.2 (blocks of 8,192 states: at most 1.7 and 8.6): one
# pass takes a block; a denser block takes more.
SIZES = {
    "gpu": IndexSizes(1, 3, 10, 1 << 29, 1 << 16, 64, 1 << 12, 1 << 22, 16, 4),
    "cpu": IndexSizes(8, 3, 10, 1 << 26, 1 << 13, 64, 1 << 12, 1 << 18, 16, 2),
}


def capsule_ends_kernel(robot: Robot, chunk: int | None = None, device: jax.Device | None = None):
    """jit(vmap(capsule_ends)) for `robot`, one per process, chunk and device (shared by the
    packing threads).  `chunk`: configurations per call (default: 32,768 on an accelerator,
    1,024 on the CPU, for the map's index; the planner's checks on the CPU hold a few dozen
    and ask for a smaller one, `actions.SMALL_CHUNK`).  `device`: JAX's default one unless
    given."""
    from kernels.collision import capsule_ends

    if chunk is None:
        chunk = 1 << 15 if backend() != "cpu" else 1024
    key = (robot.model_hash, chunk, None if device is None else device.id)
    with _ENDS_LOCK:
        if key not in _ENDS:

            def one(q):
                return capsule_ends(robot.arm, q)

            _ENDS[key] = ChunkedKernel(
                ("capsule_ends", robot.model_hash), one, [], [(np.float32, (robot.nq,))], chunk, device=device
            )
        return _ENDS[key]


@dataclass(frozen=True)
class Grid:
    """The reach grid as the index sees it: its lower corner, cell and size."""

    x0: float
    y0: float
    cell: float
    nx: int
    ny: int

    @classmethod
    def of(cls, reach: ReachResult) -> Grid:
        cell = reach.config.cell
        ny, nx = reach.labels.shape
        return cls(reach.xs[0] - cell / 2, reach.ys[0] - cell / 2, cell, nx, ny)


def neighbourhood(radius: float, cell: float) -> int:
    """Cells tested on each side of a sample's cell for capsules of radius at most `radius`."""
    return int(np.ceil(radius / cell))


class IndexTotals:
    """What the index did in this process (summed over threads): batches, states, passes
    (those beyond a block's first: `extra_passes`), borderline items settled on the host,
    blocks settled whole on the host, pairs, seconds, and seconds compiling its programs."""

    KEYS = ("batches", "states", "passes", "extra_passes", "borderline", "host_blocks", "pairs", "seconds",
            "compile_seconds")  # fmt: skip

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._v = dict.fromkeys(self.KEYS, 0.0)

    def add(self, **kw: float) -> None:
        with self._lock:
            for k, v in kw.items():
                self._v[k] += v

    def snapshot(self) -> dict[str, float]:
        with self._lock:
            return dict(self._v)


TOTALS = IndexTotals()


def index_totals(since: dict[str, float] | None = None) -> dict[str, float]:
    """The index's totals in this process (less those of `since`, an earlier snapshot)."""
    now = TOTALS.snapshot()
    if since is not None:
        now = {k: v - since.get(k, 0.0) for k, v in now.items()}
    return {k: round(v, 4) if k.endswith("seconds") else int(v) for k, v in now.items()}


class ArmIndex:
    """The index programs of one robot, reach grid and device (`pairs`).  Thread-safe: each
    call has its own map of marks."""

    def __init__(self, robot: Robot, nx: int, ny: int, cell: float, device: jax.Device | None = None) -> None:
        arm = robot.arm
        self.robot = robot
        self.device = device if device is not None else jax.local_devices()[0]
        self.sizes = SIZES["cpu" if self.device.platform == "cpu" else "gpu"]
        self.ends = capsule_ends_kernel(robot, device=device)
        caps = tuple(int(c) for c in np.asarray(arm.table_caps))
        radii = tuple(float(r) for r in np.asarray(arm.cap_r, np.float64)[list(caps)])
        reach = neighbourhood(max(radii, default=0.0), cell)
        per_edge = ny * (nx + 2 * reach)  # marks of an edge
        edges = 32
        while edges * 2 <= min(self.sizes.edges, self.sizes.marks_bytes // (4 * per_edge), INT32_MAX // per_edge):
            edges *= 2
        states = self.ends.chunk * self.sizes.launches
        if NEIGHBOURHOOD_STATES % states:
            raise ValueError(f"a pass of {states} states must divide {NEIGHBOURHOOD_STATES}")
        # the most samples one item can have: its whole axis, in half cells, and two
        longest = max((float(np.linalg.norm(arm.cap_b[c] - arm.cap_a[c])) for c in caps), default=0.0)
        samples = max(self.sizes.samples * states, math.ceil(longest / (cell / 2)) + 2)
        self.shape = IndexShape(
            caps=caps,
            radii=radii,
            nx=nx,
            ny=ny,
            reach=reach,
            states=states,
            items=self.sizes.items * states,
            samples=samples,
            edges=edges,
            flags=self.sizes.flags,
        )
        self._lock = threading.Lock()
        self._programs: dict[str, Any] | None = None
        self.compile_seconds = 0.0

    # ----------------------------------------------------------------------------- programs

    def compile(self) -> None:
        """Compile the capsule program and the index programs (once)."""
        self.ends.compile()
        with self._lock:
            if self._programs is None:
                t0 = time.perf_counter()
                with compile_span():
                    self._programs = self._build()
                self.compile_seconds = time.perf_counter() - t0
                told_compiled("the spatial index", self.compile_seconds)
                TOTALS.add(compile_seconds=self.compile_seconds)

    def _build(self) -> dict[str, Any]:
        import jax.numpy as jnp
        from jax.sharding import SingleDeviceSharding

        sh, sz = self.shape, self.sizes
        on = SingleDeviceSharding(self.device)
        ends_shape = (self.ends.chunk, len(self.robot.arm.cap_r), 3)

        def spec(shape, dtype):
            return jax.ShapeDtypeStruct(shape, dtype, sharding=on)

        def one_pass(marks, a_parts, b_parts, ints, starts, words):
            a = jnp.concatenate(a_parts) if len(a_parts) > 1 else a_parts[0]
            b = jnp.concatenate(b_parts) if len(b_parts) > 1 else b_parts[0]
            return index_pass(sh, marks, a, b, ints, starts, words)

        marks = spec((sh.size,), jnp.int32)
        parts = tuple(spec(ends_shape, jnp.float32) for _ in range(sz.launches))
        words = spec((2 * len(PARAMS),), jnp.uint32)
        # float64 in the trace only: the programs take and give 32-bit values
        with jax.enable_x64(True):
            return {
                "pass": jax.jit(one_pass, donate_argnums=0)
                .lower(marks, parts, parts, spec((5,), jnp.int32), spec((sh.edges + 1,), jnp.int32), words)
                .compile(),
                "mark": jax.jit(lambda m, e, c: mark_cells(sh, m, e, c), donate_argnums=0)
                .lower(marks, spec((sz.marks,), jnp.int32), spec((sz.marks,), jnp.int32))
                .compile(),
                "window": jax.jit(lambda m, off: extract_pairs(sh, m, off, sz.out, sz.out_blocks))
                .lower(marks, spec((), jnp.int32))
                .compile(),
                "empty": jax.jit(lambda: empty_marks(sh), out_shardings=on).lower().compile(),
            }

    def _put(self, x: np.ndarray) -> jax.Array:
        return jax.device_put(x, self.device)

    # ----------------------------------------------------------------------------- pairs

    def pairs(self, grid: Grid, q: np.ndarray, length: np.ndarray, height: float) -> tuple[np.ndarray, np.ndarray]:
        """(cell, edge) pairs, unique and sorted by cell then edge, of the edges of `length`
        states each, their states `q` (S, nq) flat (see `arm_index_pairs`)."""
        q = np.asarray(q, np.float32)

        def launch(part: np.ndarray) -> tuple[jax.Array, jax.Array]:
            out = self.ends.launch(q[part])
            return out["a"], out["b"]

        return self._pairs(grid, len(q), length, height, launch)

    def pairs_of_ends(
        self, grid: Grid, a: np.ndarray, b: np.ndarray, length: np.ndarray, height: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """The same pairs of states given by their capsules' ends a, b (S, nc, 3) float32 (as
        the capsule program gives them) rather than their joint angles."""
        a, b = np.asarray(a, np.float32), np.asarray(b, np.float32)
        return self._pairs(grid, len(a), length, height, lambda part: (self._put(a[part]), self._put(b[part])))

    def _pairs(self, grid: Grid, n: int, length: np.ndarray, height: float, launch) -> tuple[np.ndarray, np.ndarray]:
        if n == 0 or len(length) == 0 or not self.shape.caps:
            return np.zeros(0, np.int32), np.zeros(0, np.int32)
        self.compile()
        t0 = time.perf_counter()
        starts = np.zeros(len(length) + 1, np.int64)
        starts[1:] = np.cumsum(length)
        words = self._put(params_words(_params(grid, height, self.robot.arm.table_z)))
        run = _Run(self, grid, height, n, starts, words, launch)
        g = self.shape.edges  # edges per map of marks
        groups = [run.group(g0, min(g0 + g, len(length))) for g0 in range(0, len(length), g)]
        cells, edges = merge_groups(groups, self.shape.cells)
        TOTALS.add(batches=1, states=n, pairs=len(cells), seconds=time.perf_counter() - t0)
        return cells, edges


def _params(grid: Grid, height: float, table_z: float) -> dict[str, float]:
    return {"x0": grid.x0, "y0": grid.y0, "cell": grid.cell, "half": grid.cell / 2, "height": height,
            "table_z": table_z}  # fmt: skip


class _Run:
    """One batch's index: its groups of edges, one map of marks at a time."""

    def __init__(self, index: ArmIndex, grid: Grid, height: float, n: int, starts: np.ndarray, words, launch) -> None:
        self.ix, self.grid, self.height, self.n, self.starts, self.words = index, grid, height, n, starts, words
        self.launch = launch  # rows (a launch's, padded) -> their capsule ends on the device
        self.p = index._programs
        self.low_caps: dict[int, np.ndarray] = {}  # pass block -> capsules low in it

    def ends(self, block: int) -> tuple[tuple, tuple]:
        """The capsule ends of pass `block`'s states, launch by launch, on the device (a launch
        past the batch's states repeats the last one: its states are not looked at)."""
        ch = self.ix.ends.chunk
        a_parts, b_parts = [], []
        for launch in range(self.ix.sizes.launches):
            lo = block * self.ix.shape.states + launch * ch
            if lo >= self.n:
                a_parts.append(a_parts[-1])
                b_parts.append(b_parts[-1])
                continue
            # padded as ChunkedKernel.run pads: the rows stay where they were in the launch
            rows = np.minimum(np.arange(lo, lo + ch), self.n - 1)
            a, b = self.launch(rows)
            a_parts.append(a)
            b_parts.append(b)
        return tuple(a_parts), tuple(b_parts)

    def group(self, g0: int, g1: int) -> tuple[np.ndarray, np.ndarray]:
        """The pairs of edges [g0, g1): edges (numbered in the batch) in (cell, edge) order and
        the pairs per cell."""
        ix, sh = self.ix, self.ix.shape
        lo, hi = int(self.starts[g0]), int(self.starts[g1])
        starts = np.full(sh.edges + 1, INT32_MAX, np.int32)
        starts[: g1 - g0 + 1] = self.starts[g0 : g1 + 1]
        starts_d = ix._put(starts)
        marks = self.p["empty"]()
        flagged: list[tuple[int, np.ndarray, np.ndarray]] = []  # (block, item ids, ends)
        host_blocks: set[int] = set()
        inflight: collections.deque = collections.deque()
        passes = extra = borderline = 0

        def settle(entry) -> None:
            """Read a pass's counts; run the passes its block still needs."""
            nonlocal marks, extra, borderline
            block, a, b, ints, out = entry
            while True:
                counts, self.low_caps[block] = jax.device_get((out.counts, out.low_caps))
                n_flag = int(counts[2])
                borderline += n_flag
                if n_flag > sh.flags:
                    host_blocks.add(block)
                elif n_flag:
                    ids, ends = jax.device_get((out.flag_ids, out.flag_ends))
                    flagged.append((block, ids[:n_flag], ends[:n_flag]))
                if counts[1] >= counts[0]:
                    return
                ints = ints.copy()
                ints[2] = counts[1]
                out = self.p["pass"](marks, a, b, ix._put(ints), starts_d, self.words)
                marks = out.marks
                extra += 1

        for block in range(lo // sh.states, (hi - 1) // sh.states + 1):
            s0 = block * sh.states
            a, b = self.ends(block)
            ints = np.array([s0, min(sh.states, self.n - s0), 0, lo, hi], np.int32)
            out = self.p["pass"](marks, a, b, ix._put(ints), starts_d, self.words)
            marks = out.marks
            passes += 1
            inflight.append((block, a, b, ints, out))
            if len(inflight) > ix.sizes.lag:
                settle(inflight.popleft())
        while inflight:
            settle(inflight.popleft())
        # every item of such a block (the device's marks of it are right, but incomplete)
        for block in sorted(host_blocks):
            a, b = self.ends(block)
            caps = list(sh.caps)
            a_h = np.concatenate([np.asarray(x) for x in a])[:, caps].reshape(-1, 3)
            b_h = np.concatenate([np.asarray(x) for x in b])[:, caps].reshape(-1, 3)
            ids = np.arange(len(a_h), dtype=np.int64)
            flagged.append((block, ids, np.concatenate([a_h, b_h], axis=1)))
        cells, edges = self._settled(flagged, g0, lo, hi)
        for i in range(0, len(cells), ix.sizes.marks):
            e, c = np.full(ix.sizes.marks, -1, np.int32), np.zeros(ix.sizes.marks, np.int32)
            e[: len(edges[i : i + ix.sizes.marks])] = edges[i : i + ix.sizes.marks]
            c[: len(cells[i : i + ix.sizes.marks])] = cells[i : i + ix.sizes.marks]
            marks = self.p["mark"](marks, ix._put(e), ix._put(c))
        TOTALS.add(passes=passes + extra, extra_passes=extra, host_blocks=len(host_blocks), borderline=borderline)
        return self._read(marks, g0)

    def _settled(self, flagged: list, g0: int, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
        """The (cell, edge) pairs of the borderline items (edges numbered in the group), by
        the reference arithmetic; only items of the group's states [lo, hi)."""
        sh = self.ix.shape
        if not flagged:
            return np.zeros(0, np.int32), np.zeros(0, np.int32)
        nt = len(sh.caps)
        block = np.concatenate([np.full(len(ids), b, np.int64) for b, ids, _ in flagged])
        ids = np.concatenate([np.asarray(ids, np.int64) for _, ids, _ in flagged])
        ends = np.concatenate([np.asarray(e, np.float32) for _, _, e in flagged])
        state = block * sh.states + ids // nt
        cap = ids % nt
        keep = (state >= lo) & (state < hi) & (state < self.n)
        state, cap, ends, block = state[keep], cap[keep], ends[keep], block[keep]
        radii = np.asarray(sh.radii, np.float64)
        edge = np.searchsorted(self.starts, state, side="right") - 1 - g0
        own = np.array([neighbourhood(radii[c], self.grid.cell) for c in range(nt)])[cap]
        # the cells tested around a sample: the neighbourhood of the largest low capsule of its
        # block's states; the item's own (its radius's) and the widest give the same cells
        # unless a hit lies between them, when the block's low capsules are needed
        g = self.grid
        args = (ends[:, :3], ends[:, 3:], radii[cap], edge, (g.x0, g.y0, g.cell, g.nx, g.ny), self.height,
                self.ix.robot.arm.table_z)  # fmt: skip
        narrow = settle_items(*args, own)
        wide = settle_items(*args, np.full(len(cap), sh.reach))
        if not np.array_equal(narrow[0], wide[0]) or not np.array_equal(narrow[1], wide[1]):
            reach = np.array([self._block_reach(int(s), int(c)) for s, c in zip(state, cap, strict=True)])
            narrow = settle_items(*args, reach)
        return narrow

    def _block_reach(self, state: int, cap: int) -> int:
        """The neighbourhood of the states [k, k + NEIGHBOURHOOD_STATES) holding `state`: of
        the largest capsule low in any of them (`cap`, low at `state`, among them)."""
        sh = self.ix.shape
        first = state // NEIGHBOURHOOD_STATES * NEIGHBOURHOOD_STATES // sh.states
        low = np.zeros(len(sh.caps), bool)
        low[cap] = True
        for block in range(first, first + NEIGHBOURHOOD_STATES // sh.states):
            if block * sh.states >= self.n:
                break
            if block not in self.low_caps:  # a pass over no group's states: its low capsules only
                a, b = self.ends(block)
                ints = np.array([block * sh.states, min(sh.states, self.n - block * sh.states), 0, 0, 0], np.int32)
                marks = self.p["empty"]()
                starts = self.ix._put(np.full(sh.edges + 1, INT32_MAX, np.int32))
                out = self.p["pass"](marks, a, b, self.ix._put(ints), starts, self.words)
                self.low_caps[block] = np.asarray(out.low_caps)
            low |= self.low_caps[block]
        return neighbourhood(float(np.asarray(sh.radii)[low].max()), self.grid.cell)

    def _read(self, marks, g0: int) -> tuple[np.ndarray, np.ndarray]:
        """The group's pairs from its marks: edges in (cell, edge) order, pairs per cell."""
        sz = self.ix.sizes
        size = sz.out // sz.out_blocks
        parts: list[np.ndarray] = []
        off, total, counts = 0, None, None
        while total is None or off < total:
            window = self.p["window"](marks, self.ix._put(np.int32(off)))
            if counts is None:
                counts = np.asarray(window.counts).astype(np.int64)
                total = int(counts.sum())
            n = min(total - off, sz.out)
            wanted = window.blocks[: -(-n // size)]
            for blk in wanted:
                blk.copy_to_host_async()
            got = np.concatenate([np.asarray(blk) for blk in wanted]) if wanted else np.zeros(0, np.int32)
            parts.append(got[:n])
            off += sz.out
        edges = np.concatenate(parts) + g0 if parts else np.zeros(0, np.int64)
        return edges.astype(np.int32), counts


_INDEXES: dict[tuple, ArmIndex] = {}
_INDEXES_LOCK = threading.Lock()


def arm_index(robot: Robot, nx: int, ny: int, cell: float, device: jax.Device | None = None) -> ArmIndex:
    """The index programs of a robot and reach grid on a device (one per process)."""
    key = (robot.model_hash, nx, ny, cell, None if device is None else device.id)
    with _INDEXES_LOCK:
        if key not in _INDEXES:
            _INDEXES[key] = ArmIndex(robot, nx, ny, cell, device)
        return _INDEXES[key]


def warm_index(robot: Robot, nx: int, ny: int, cell: float) -> None:
    """Compile the index programs of a reach grid on every device `arm_index_pairs` uses:
    the first device's, then the others' side by side (the same programs placed elsewhere,
    which JAX's persistent cache then holds: loaded, not compiled again each)."""
    first, *others = index_devices()
    arm_index(robot, nx, ny, cell, first).compile()
    if others:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(len(others), thread_name_prefix="lmjx-compile") as pool:
            for done in [pool.submit(arm_index(robot, nx, ny, cell, d).compile) for d in others]:
                done.result()


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
    capsule's radius of its square.  Computed on the local devices in turn (`ArmIndex`)."""
    grid = Grid.of(reach)
    index = arm_index(robot, grid.nx, grid.ny, grid.cell, next_device())
    return index.pairs(grid, q, length, height)


def csr(cells: np.ndarray, edges: np.ndarray, n_cells: int) -> tuple[np.ndarray, np.ndarray]:
    """CSR offsets (n_cells + 1,) and edge ids of (cell, edge) pairs sorted by cell."""
    offset = np.zeros(n_cells + 1, np.int64)
    offset[1:] = np.cumsum(np.bincount(cells, minlength=n_cells))
    return offset, edges.astype(np.int32)
