"""Writing map files: the Reach-Ability map, the edge bundle (whole, or streamed chunk by
chunk with `EdgeWriter`) and the spatial index; every file written atomically (temporary
file, then rename), so an interrupted write never leaves a corrupt map, and every chunked
dataset with HDF5's Fletcher-32 checksum, so that a later damage is detected on reading.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import h5py
import numpy as np

from lmjx import __version__
from lmjx.errors import MapFileError
from lmjx.mapfile.checksum import with_checksum
from lmjx.mapfile.digest import store_digest
from lmjx.mapfile.h5 import h5open
from lmjx.mapfile.pushcounts import write_push_counts
from lmjx.mapfile.schema import (
    DEFLATE_LEVEL,
    EDGE_ROWS,
    LABEL_MEANING,
    PER_EDGE,
    PER_STATE,
    SCHEMA,
    SCHEMA_VERSION,
    STATE_ROWS,
    STR_DTYPE,
    config_to_attrs,
)
from lmjx.runtime.cores import usable_cores
from lmjx.runtime.fileio import atomic_path

if TYPE_CHECKING:  # (the map-writing process appends edges without the robot's model or JAX: `edges.mapappend`)
    from lmjx.mapfile.bundle import Bundle, BundleConfig
    from lmjx.mapfile.pushbuild import BuildPushCounts
    from lmjx.model.failure import Failure
    from lmjx.model.robot import Robot
    from lmjx.reach.reachability import ReachResult

try:  # Intel ISA-L's deflate: standard deflate streams (any HDF5 reads them), 6-10x faster
    from isal import isal_zlib as _deflate  # than zlib on these floats, sizes within 3 %
except ImportError:  # pragma: no cover - isal is a dependency; zlib gives the same files' data
    import zlib as _deflate


def _dataset(group: h5py.Group, name: str, data: np.ndarray, doc: str, compress: bool = True) -> None:
    """A dataset of `data`, with HDF5's Fletcher-32 checksum (chunked) unless it is a scalar or
    empty; gzip-compressed when `compress` and of 64 values or more."""
    data = np.asarray(data)
    kwargs: dict = {"track_times": False}
    if data.ndim and data.size:
        kwargs.update(chunks=True, fletcher32=True)
    if compress and data.size >= 64:
        kwargs.update(compression="gzip", compression_opts=4, shuffle=True)
    ds = group.create_dataset(name, data=data, **kwargs)
    ds.attrs["doc"] = doc


def _write_robot(f: h5py.File, robot: Robot) -> None:
    g = f.create_group("robot", track_order=True)
    g.attrs["doc"] = "The robot the map was built for; mjcf holds the full model text."
    g.create_dataset("mjcf", data=robot.path.read_text(encoding="utf-8"), dtype=STR_DTYPE, track_times=False)
    g.create_dataset("joint_names", data=np.array(robot.joint_names, dtype=object), dtype=STR_DTYPE, track_times=False)
    g.create_dataset("site_names", data=np.array(robot.site_names, dtype=object), dtype=STR_DTYPE, track_times=False)
    for name, arr, doc in (
        ("lower", robot.lower, "joint position lower limits [rad]"),
        ("upper", robot.upper, "joint position upper limits [rad]"),
        ("qd_max", robot.qd_max, "joint velocity limits [rad/s]"),
        ("qdd_max", robot.qdd_max, "joint acceleration limits [rad/s^2]"),
        ("jerk_max", robot.jerk_max, "joint jerk limits [rad/s^3]"),
        ("tau_max", robot.tau_max, "joint torque limits [Nm]"),
    ):
        _dataset(g, name, np.asarray(arr, np.float64), doc, compress=False)


def _write_reach(f: h5py.File, result: ReachResult) -> None:
    g = f.create_group("reach", track_order=True)
    g.attrs["doc"] = "Reach-Ability map (paper Algorithm 1); arrays indexed [iy, ix]."
    config_to_attrs(g, result.config)
    eps = result.config.epsilon if result.config.epsilon is not None else result.config.cell / 2
    g.attrs["epsilon_used"] = eps
    areas, raw = result.areas(True), result.areas(False)
    g.attrs["area_pm_m2"] = areas["pm"]
    g.attrs["area_npm_pm_m2"] = areas["npm_pm"]
    g.attrs["area_raw_pm_m2"] = raw["pm"]
    g.attrs["area_raw_npm_pm_m2"] = raw["npm_pm"]
    g.attrs["seconds"] = result.seconds
    g.attrs["compile_seconds"] = result.compile_seconds
    g.attrs["kernel_seconds"] = result.kernel_seconds
    g.attrs["device"] = result.device
    g.attrs["problems"] = result.problems
    _dataset(g, "x", result.xs, "cell centres along x [m]", compress=False)
    _dataset(g, "y", result.ys, "cell centres along y [m]", compress=False)
    _dataset(g, "labels", result.labels.astype(np.int8), f"raw labels: {LABEL_MEANING}")
    _dataset(
        g,
        "labels_smooth",
        result.labels_smooth.astype(np.int8),
        f"labels after hole filling: {LABEL_MEANING}",
    )
    _dataset(g, "q", result.q.astype(np.float32), "accepted joint angles J1..J7 [rad], NaN where unreachable")
    _dataset(g, "attempt", result.attempt.astype(np.int8), "first successful attempt (0-based), -1 if none")
    _dataset(g, "site", result.site.astype(np.int16), "index into /robot/site_names of the solved site, -1 if none")
    _dataset(g, "target", result.target.astype(np.float32), "solved target: x, y, z_lo, z_hi [m], NaN if none")
    _dataset(g, "pos_err", result.pos_err.astype(np.float32), "distance of the solved site to its target [m]")


def write_reach_map(
    path: str | Path, result: ReachResult, robot: Robot | str | Path | None = None, overwrite: bool = False
) -> None:
    """Write a map file holding only a Reach-Ability map (what `lmjx reach --out` writes;
    schema: maps/README.md); atomic (temp file, then rename), its folder made where missing.
    `robot`: the robot the map was computed for (a Robot, a name or an MJCF's path); None: the
    shipped robot whose model the result names.  A file already at `path` is refused with a
    one-line `OutputPathError` unless `overwrite` is true (as `lmjx reach --out` refuses one
    without `--overwrite`).

    >>> import lmjx
    >>> res = lmjx.reach_map("case2", lmjx.ReachConfig(cell=0.1))
    >>> lmjx.write_reach_map("out/case2_reach.h5", res)
    """
    from lmjx.errors import OutputPathError

    p = Path(path)
    if p.is_dir():
        raise OutputPathError(f"{p} is a folder; give the map file's name")
    if p.exists() and not overwrite:
        raise OutputPathError(f"{p} already exists; pass overwrite=True to replace it, or choose another path")
    write_map(p, result, None, robot)


def _robot_of(reach: ReachResult) -> Robot:
    """The shipped robot a result was computed for (by its model's hash)."""
    from lmjx.model.robot import ROBOTS, load_robot

    for robot in map(load_robot, ROBOTS):
        if robot.model_hash == reach.robot_hash:
            return robot
    raise MapFileError("this map was computed for a user's robot: pass robot= (its MJCF's path or the Robot)")


def write_map(
    path: str | Path, reach: ReachResult, bundle: Bundle | None, robot: Robot | str | Path | None = None
) -> dict:
    """Write a map file: the Reach-Ability map and, when given, the edge bundle with the
    push counts of the robot's built-in scenarios (`mapfile.pushcounts`, computed from the
    edges as written), and the map's content digest (`mapfile.digest`).  Atomic (temp file,
    then rename).  Returns storage figures (bytes per stored edge state) and the push
    counts' time."""
    from lmjx.model.robot import as_robot

    robot = as_robot(robot) if robot is not None else _robot_of(reach)
    sizes: dict = {}
    with atomic_path(path) as tmp:
        with h5open(tmp, "w", track_order=True) as f:
            write_head(f, robot, reach, with_edges=bundle is not None)
            if bundle is not None:
                w = EdgeWriter(f, bundle.config, reach, robot.nq)
                w.add_states(bundle.q, bundle.qd, bundle.p)
                w.add_edges({name: getattr(bundle, name) for name in PER_EDGE})
                write_index(w.group, IndexGrid.of(reach), bundle.index_offset, bundle.index_edges)
                sizes = w.close(bundle_attrs(bundle))
        if bundle is not None:
            sizes |= store_push_counts(tmp, robot)
        store_digest(tmp)
        if bundle is not None and bundle.n_states:
            sizes["file_bytes_per_state"] = Path(tmp).stat().st_size / bundle.n_states
    return sizes


def write_head(f: h5py.File, robot: Robot, reach: ReachResult, with_edges: bool) -> None:
    """Root attributes, /robot and /reach of a map file."""
    _write_header(f, robot, reach.failure, contents="reach+edges" if with_edges else "reach")
    _write_robot(f, robot)
    _write_reach(f, reach)


def bundle_attrs(b: Bundle) -> dict:
    """What /edges' attributes say about a build."""
    return {
        "edges_sampled": b.sampled,
        "rejected": b.rejected,
        "seconds": b.seconds,
        "compile_seconds": b.compile_seconds,
        "rollout_seconds": b.rollout_seconds,
        "edge_steps": b.edge_steps,
        "states_evaluated": b.states_evaluated,
        "device": b.device,
    }


class EdgeWriter:
    """Writes /edges of a map file piece by piece, in bounded memory: the states (q, qd, p,
    in HDF5 chunks of `STATE_ROWS` rows) and the per-edge arrays (`EDGE_ROWS` rows) are
    compressed with HDF5's own shuffle and deflate filters and checksummed as its Fletcher-32
    filter does (`mapfile.checksum`; readable and checked by any HDF5 library)
    on all cores and written whole chunk by whole chunk as they fill; `offset` is computed
    from the lengths.  The caller's thread only slices and writes: every copy and all the
    compression happen in the pool."""

    def __init__(
        self, f: h5py.File, config: BundleConfig | None, reach: ReachResult | None, nq: int, threads: int | None = None
    ) -> None:
        """`config`: the bundle's (None: /edges made already, `edges_group`); `reach`: unused."""
        from concurrent.futures import ThreadPoolExecutor

        self.group = edges_group(f, config) if config is not None else f["edges"]
        self.widths = {"q": nq, "qd": nq, "p": 3}
        self.columns: dict[str, _Column] = {}
        for name, doc in PER_STATE.items():
            self.columns[name] = _Column(self._dataset(name, doc, (self.widths[name],), np.dtype(np.float32)),
                                         STATE_ROWS)  # fmt: skip
        self.rows = 0  # states given
        self.threads = threads or usable_cores()
        self.pool = ThreadPoolExecutor(self.threads, thread_name_prefix="lmjx-write")
        # chunks being compressed and written by the pool, so the caller goes on while the
        # pool works (at most `4 x threads` in flight)
        self.inflight: collections.deque = collections.deque()  # (chunks, job)
        self.in_flight = 0  # chunks
        self.n_edges = 0
        self.next_offset = 0

    def _dataset(self, name: str, doc: str, shape: tuple[int, ...], dtype: np.dtype) -> h5py.Dataset:
        rows = STATE_ROWS if name in PER_STATE else EDGE_ROWS
        ds = self.group.create_dataset(name, shape=(0, *shape), maxshape=(None, *shape), dtype=dtype,
                                       chunks=(rows, *shape), compression="gzip", compression_opts=DEFLATE_LEVEL,
                                       shuffle=True, fletcher32=True, track_times=False)  # fmt: skip
        ds.attrs["doc"] = doc
        return ds

    def add_states(self, q: np.ndarray, qd: np.ndarray, p: np.ndarray) -> None:
        for name, rows in (("q", q), ("qd", qd), ("p", p)):
            self.columns[name].add(np.asarray(rows, np.float32))
        self.rows += len(q)
        self._flush(final=False)

    def add_edges(self, arrays: dict[str, np.ndarray]) -> None:
        """Per-edge arrays (`PER_EDGE`) of the next edges, whose states came already, in order."""
        length = np.asarray(arrays["length"])
        offset = self.next_offset + np.concatenate([[0], np.cumsum(length)[:-1]]).astype(np.int64)
        self.next_offset += int(length.sum())
        for name, data in {"offset": offset[: len(length)], **arrays}.items():
            data = np.asarray(data)
            if name not in self.columns:
                doc = "first row of each edge in q, qd, p" if name == "offset" else PER_EDGE[name]
                self.columns[name] = _Column(self._dataset(name, doc, data.shape[1:], data.dtype), EDGE_ROWS)
            self.columns[name].add(data)
        self.n_edges += len(length)
        self._flush(final=False)

    def _flush(self, final: bool) -> None:
        """Hand every whole chunk (all that is left, when `final`) to the pool, `GROUP`
        consecutive chunks a job: each job assembles, shuffles, compresses and writes its
        chunks (HDF5 calls are serialised by h5py; chunks land in any order, each at its
        own rows).  Few interpreter-lock round trips per chunk: with dozens of busy threads
        they, not the compression, set the pace."""
        for col in self.columns.values():
            chunks = col.chunks(final)
            for i in range(0, len(chunks), GROUP):
                group = chunks[i : i + GROUP]
                job = self.pool.submit(_write_chunks, col.ds, group, col.rows_per_chunk, col.dtype, col.fletcher)
                self.inflight.append((len(group), job))
                self.in_flight += len(group)
        self._wait(final)

    def _wait(self, everything: bool) -> None:
        """Collect the jobs done (raising a writing error here), and wait for the oldest
        while more than `4 x threads` chunks are in flight (or, `everything`, for all)."""
        most = 4 * self.threads
        while self.inflight and (everything or self.in_flight > most or self.inflight[0][1].done()):
            n, job = self.inflight.popleft()
            job.result()
            self.in_flight -= n

    def close(self, attrs: dict) -> dict:
        """The last states, the build's attributes; storage figures back."""
        self._flush(final=True)
        self.pool.shutdown()
        g = self.group
        g.attrs["edges_sampled"] = attrs["edges_sampled"]
        g.attrs["edges_valid"] = self.n_edges
        for reason, count in attrs["rejected"].items():
            g.attrs[f"rejected_{reason}"] = count
        for k in ("seconds", "compile_seconds", "rollout_seconds", "edge_steps", "states_evaluated", "device"):
            g.attrs[k] = attrs[k]
        n_states = max(self.rows, 1)
        stored = sum(g[k].id.get_storage_size() for k in PER_STATE)
        raw = sum(self.rows * self.widths[k] * 4 for k in PER_STATE)
        g.attrs["bytes_per_state"] = stored / n_states
        g.attrs["raw_bytes_per_state"] = raw / n_states
        return {"bytes_per_state": stored / n_states, "raw_bytes_per_state": raw / n_states}


class _Column:
    """One growing dataset's rows not yet handed to the compressors (views of the caller's
    arrays), cut into whole HDF5 chunks."""

    def __init__(self, ds: h5py.Dataset, rows_per_chunk: int, grow: bool = True) -> None:
        self.ds, self.rows_per_chunk, self.grow = ds, rows_per_chunk, grow  # grow: the dataset with its rows
        self.dtype = ds.dtype  # kept: each h5py call waits for h5py's lock, held by the writing threads
        self.fletcher = ds.fletcher32
        self.pending: collections.deque[np.ndarray] = collections.deque()
        self.waiting = 0  # rows in `pending`
        self.written = 0  # rows handed on (whole chunks, until the last)

    def add(self, rows: np.ndarray) -> None:
        if len(rows):
            self.pending.append(rows)
            self.waiting += len(rows)

    def chunks(self, final: bool) -> list[tuple[int, list[np.ndarray]]]:
        """(first row, pieces) of each whole chunk waiting, and of the last part when
        `final`; the dataset is grown once to hold them."""
        size = self.rows_per_chunk
        out = []
        while self.waiting >= size or (final and self.waiting):
            take = min(size, self.waiting)
            pieces, need = [], take
            while need:
                x = self.pending[0]
                if len(x) <= need:
                    pieces.append(self.pending.popleft())
                    need -= len(x)
                else:
                    pieces.append(x[:need])
                    self.pending[0] = x[need:]
                    need = 0
            out.append((self.written, pieces))
            self.written += take
            self.waiting -= take
        if out and self.grow:
            self.ds.resize(self.written, axis=0)
        return out


def write_rows(ds: h5py.Dataset, parts: Iterable[np.ndarray], threads: int) -> None:
    """All the rows of a chunked dataset of its final shape, stored as `EdgeWriter` stores
    its datasets (HDF5's shuffle, deflate and Fletcher-32 filters), given in order in parts
    of any length: assembled into whole chunks, compressed a few chunks a job on `threads`
    threads and written chunk by chunk.  h5py's own writes compress one chunk at a time:
    the spatial index of a 5,000,000-edge map (128 M edge ids) took about 10 s so."""
    from concurrent.futures import ThreadPoolExecutor

    if ds.chunks is None:  # an empty dataset, stored whole (`write_index`): no rows to write
        if any(len(part) for part in parts):
            raise ValueError(f"{ds.name}: rows given for a dataset of {len(ds)}")
        return
    col = _Column(ds, ds.chunks[0], grow=False)
    jobs: collections.deque = collections.deque()
    with ThreadPoolExecutor(threads, thread_name_prefix="lmjx-write") as pool:

        def flush(final: bool) -> None:
            chunks = col.chunks(final)
            for i in range(0, len(chunks), GROUP):
                jobs.append(pool.submit(_write_chunks, ds, chunks[i : i + GROUP], col.rows_per_chunk, col.dtype,
                                        col.fletcher))  # fmt: skip
            while jobs and (len(jobs) > 4 * threads or jobs[0].done()):
                jobs.popleft().result()

        for part in parts:
            col.add(part)
            flush(final=False)
        flush(final=True)
        while jobs:
            jobs.popleft().result()


GROUP = 4  # consecutive chunks of a dataset written by one job of EdgeWriter's pool


def _write_chunks(ds: h5py.Dataset, chunks: list[tuple[int, list[np.ndarray]]], rows: int, dtype: np.dtype,
                  fletcher: bool | None = None) -> None:  # fmt: skip
    """Consecutive chunks (first row, pieces) of `ds`, assembled in one zero-padded block
    and shuffled at once, then compressed, checksummed where `ds` has HDF5's Fletcher-32
    filter (`fletcher`; None: ask `ds`) and written one by one: the bytes HDF5's shuffle,
    deflate (and Fletcher-32) filters would store."""
    fletcher = ds.fletcher32 if fletcher is None else fletcher
    first = chunks[0][1][0]
    block = np.zeros((len(chunks) * rows, *first.shape[1:]), dtype)
    at = 0
    for k, (_, pieces) in enumerate(chunks):
        at = k * rows
        for x in pieces:
            block[at : at + len(x)] = x
            at += len(x)
    size = block.dtype.itemsize
    shuffled = np.ascontiguousarray(block.view(np.uint8).reshape(len(chunks), -1, size).transpose(0, 2, 1))
    zeros = (0,) * (first.ndim - 1)
    for (row, _), data in zip(chunks, shuffled, strict=True):
        packed = _deflate.compress(data, DEFLATE_LEVEL)
        ds.id.write_direct_chunk((row, *zeros), with_checksum(packed) if fletcher else packed, 0)


def edges_group(f: h5py.File, config: BundleConfig) -> h5py.Group:
    """/edges, with the bundle's settings as attributes (and nothing else yet)."""
    g = f.create_group("edges", track_order=True)
    g.attrs["doc"] = (
        "Edge bundle (paper Algorithm 2): valid edges stored flat; edge e's states are rows "
        "offset[e] .. offset[e] + length[e] - 1 of q, qd and p."
    )
    config_to_attrs(g, config)
    g.attrs["steps_max"] = config.steps
    return g


class IndexGrid(NamedTuple):
    """The reach grid the spatial index is over."""

    nx: int
    ny: int
    cell: float  # [m]

    @classmethod
    def of(cls, reach: ReachResult) -> IndexGrid:
        return cls(len(reach.xs), len(reach.ys), float(reach.config.cell))


def write_index(g: h5py.Group, grid: IndexGrid, offset: np.ndarray, edges: np.ndarray | None) -> h5py.Dataset:
    """/edges/index: the CSR offsets, and the edge ids (`edges`, or left for the caller to
    fill into the returned dataset when None)."""
    idx = g.create_group("index", track_order=True)
    idx.attrs["doc"] = (
        "Edges over each reach cell (CSR): the edges of cell c = iy * nx + ix are "
        "edges[offset[c] : offset[c + 1]]; an edge is listed when its interaction point passes "
        "over the cell with the link's lowest surface at most `height` above the table."
    )
    idx.attrs["nx"] = grid.nx
    idx.attrs["ny"] = grid.ny
    idx.attrs["cell"] = grid.cell
    idx.attrs["height"] = float(g.attrs["index_height"])
    _dataset(idx, "offset", offset, "CSR offsets, length ny * nx + 1")
    if edges is not None:
        _dataset(idx, "edges", edges, "edge ids")
        return idx["edges"]
    total = int(offset[-1])
    if total == 0:  # stored as `write_map` stores an empty index (HDF5 chunks no empty dataset of a fixed shape)
        _dataset(idx, "edges", np.zeros(0, np.int32), "edge ids")
        return idx["edges"]
    ds = idx.create_dataset(
        "edges",
        shape=(total,),
        dtype=np.int32,
        chunks=(min(max(total, 1), 1 << 18),),
        compression="gzip",
        compression_opts=DEFLATE_LEVEL,  # (filled by `write_rows`)
        shuffle=True,
        fletcher32=True,
        track_times=False,
    )
    ds.attrs["doc"] = "edge ids"
    return ds


def _write_header(f: h5py.File, robot: Robot, failure: Failure, contents: str) -> None:
    f.attrs["schema"] = SCHEMA
    f.attrs["schema_version"] = SCHEMA_VERSION
    f.attrs["lmjx_version"] = __version__
    from lmjx.model.robot import ROBOTS

    f.attrs["robot"] = robot.key if robot.key in ROBOTS else robot.name
    f.attrs["robot_model"] = robot.name
    f.attrs["robot_model_hash"] = robot.model_hash
    f.attrs["failure"] = failure.spec
    f.attrs["locked_joints"] = np.array([j for j, _ in failure.locked], dtype=np.int32)
    f.attrs["locked_angles"] = np.array([a for _, a in failure.locked], dtype=np.float64)
    f.attrs["contents"] = contents


def store_push_counts(
    path: str | Path, robot: Robot, progress: bool = False, summed: BuildPushCounts | None = None
) -> dict:
    """Compute the push counts of the map at `path` (reach map and edges written) and add
    them to it (`/edges/push`); figures back (seconds, entries).  Runs where JAX computes
    (the map's states go through the device once, `lmjx.mapfile.pushsamples`), unless
    `summed` (`lmjx.mapfile.pushbuild.BuildPushCounts`) holds them, summed over the map's
    chunks while it was built: then only their keys are computed here."""
    t0 = time.perf_counter()
    entries, attrs = push_counts_of(path, robot, progress, summed)
    with h5open(path, "r+") as f:
        write_push_counts(f["edges"], entries, attrs)
    return {"push_seconds": round(time.perf_counter() - t0, 4), "push_entries": len(entries)}


def push_counts_of(
    path: str | Path, robot: Robot, progress: bool = False, summed: BuildPushCounts | None = None
) -> tuple[list, dict]:
    """`store_push_counts`'s counts of the map at `path` (only read) and the attributes
    `write_push_counts` stores with them."""
    from lmjx.mapfile.pushmap import COUNTS_VERSION, HEIGHT, MAX_ANGLE, builtin_counts
    from lmjx.mapfile.read import load_map
    from lmjx.runtime.batching import backend
    from lmjx.sim.sceneboxes import FIXED_MARGIN, MIN_EDGE_STATES

    t0 = time.perf_counter()
    if summed is not None:
        from lmjx.mapfile.pushbuild import KeyedEdges

        with h5open(path, "r") as f:
            entries = summed.entries(KeyedEdges.read(f["edges"]))
    else:
        with load_map(path, robot, lazy=True) as m:
            assert m.edges is not None and m.reach is not None
            entries = builtin_counts(robot, m.failure, m.edges, m.reach, progress)
    seconds = time.perf_counter() - t0
    attrs = {"platform": backend(), "counts_version": COUNTS_VERSION, "max_angle_deg": MAX_ANGLE, "height_m": HEIGHT,
             "fixed_margin_m": FIXED_MARGIN, "min_edge_states": MIN_EDGE_STATES, "seconds": seconds}  # fmt: skip
    return entries, attrs
