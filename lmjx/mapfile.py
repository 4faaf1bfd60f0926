"""HDF5 map files: writing (atomically) and reading with validation.

The schema is documented in maps/README.md for readers that do not import lmjx (plain
h5py, MATLAB, C++).  Version 1 holds the Reach-Ability map; later versions of this module
add groups without changing the existing ones.
"""

from __future__ import annotations

import collections
import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from . import __version__
from .bundle import Bundle, BundleConfig
from .cores import usable_cores
from .errors import MapFileError
from .failure import Failure
from .fileio import atomic_path
from .lazystates import StateReader
from .reach import ReachConfig, ReachResult
from .robot import ROBOTS, Robot, as_robot, load_robot

SCHEMA = "lmjx-map"
SCHEMA_VERSION = 2  # 2: the spatial index lists the edges whose whole arm (swept capsules) reaches a cell
LABEL_MEANING = "0 unreachable, 1 NPM only (push/poke), 2 PM (grasp)"

_STR = h5py.string_dtype(encoding="utf-8")


def _dataset(group: h5py.Group, name: str, data: np.ndarray, doc: str, compress: bool = True) -> None:
    data = np.asarray(data)
    kwargs: dict = {"track_times": False}
    if compress and data.size >= 64:
        kwargs.update(compression="gzip", compression_opts=4, shuffle=True, chunks=True)
    ds = group.create_dataset(name, data=data, **kwargs)
    ds.attrs["doc"] = doc


def _write_robot(f: h5py.File, robot: Robot) -> None:
    g = f.create_group("robot", track_order=True)
    g.attrs["doc"] = "The robot the map was built for; mjcf holds the full model text."
    g.create_dataset("mjcf", data=robot.path.read_text(encoding="utf-8"), dtype=_STR, track_times=False)
    g.create_dataset("joint_names", data=np.array(robot.joint_names, dtype=object), dtype=_STR, track_times=False)
    g.create_dataset("site_names", data=np.array(robot.site_names, dtype=object), dtype=_STR, track_times=False)
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
    _config_to_attrs(g, result.config)
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


def write_reach_map(path: str | Path, result: ReachResult, robot: Robot | str | Path | None = None) -> None:
    """Write a map file holding only a Reach-Ability map (what `lmjx reach --out` writes;
    schema: maps/README.md); atomic (temp file, then rename).  `robot`: the robot the map was
    computed for (a Robot, a name or an MJCF's path); None: the shipped robot whose model
    the result names.

    >>> import lmjx
    >>> res = lmjx.reach_map("case2", lmjx.ReachConfig(cell=0.1))
    >>> lmjx.write_reach_map("case2_reach.h5", res)
    """
    write_map(path, result, None, robot)


def _robot_of(reach: ReachResult) -> Robot:
    """The shipped robot a result was computed for (by its model's hash)."""
    for robot in map(load_robot, ROBOTS):
        if robot.model_hash == reach.robot_hash:
            return robot
    raise MapFileError("this map was computed for a user's robot: pass robot= (its MJCF's path or the Robot)")


def write_map(
    path: str | Path, reach: ReachResult, bundle: Bundle | None, robot: Robot | str | Path | None = None
) -> dict:
    """Write a map file: the Reach-Ability map and, when given, the edge bundle.  Atomic
    (temp file, then rename).  Returns storage figures (bytes per stored edge state)."""
    robot = as_robot(robot) if robot is not None else _robot_of(reach)
    sizes: dict = {}
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w", track_order=True) as f:
            write_head(f, robot, reach, with_edges=bundle is not None)
            if bundle is not None:
                w = EdgeWriter(f, bundle.config, reach, robot.nq)
                w.add_states(bundle.q, bundle.qd, bundle.p)
                w.add_edges({name: getattr(bundle, name) for name in PER_EDGE})
                write_index(w.group, reach, bundle.index_offset, bundle.index_edges)
                sizes = w.close(bundle_attrs(bundle))
        if bundle is not None and bundle.n_states:
            sizes["file_bytes_per_state"] = Path(tmp).stat().st_size / bundle.n_states
    return sizes


def write_head(f: h5py.File, robot: Robot, reach: ReachResult, with_edges: bool) -> None:
    """Root attributes, /robot and /reach of a map file."""
    _write_header(f, robot, reach.failure, contents="reach+edges" if with_edges else "reach")
    _write_robot(f, robot)
    _write_reach(f, reach)


PER_EDGE = {
    "length": "states per edge (control steps + 1)",
    "q_start": "joint angles J1..J7 of each edge's first state [rad] (= q[offset]: where its transit goes)",
    "twist": "commanded twist of the interaction point: vx, vy, vz [m/s], wx, wy, wz [rad/s]",
    "duration": "edge duration [s] = (length - 1) * dt",
    "site": "index into /robot/site_names of the edge's interaction point",
    "start_cell": "(iy, ix) of the reach cell the edge starts from",
    "min_manipulability": "smallest sqrt(det(J J^T)) along the edge",
    "peak_torque_ratio": "max |tau_i| / tau_max_i over free joints and states",
    "peak_velocity_ratio": "max |qd_i| / qd_max_i",
    "peak_acceleration_ratio": "max |qdd_i| / qdd_max_i",
}
PER_STATE = {
    "q": "joint angles J1..J7 at each state [rad] (locked joints at their angles)",
    "qd": "joint velocities J1..J7 at each state [rad/s] (J^+ of the twist)",
    "p": "world position of the edge's interaction point at each state [m]",
}
STATE_ROWS = 16384  # rows per HDF5 chunk of q, qd, p
EDGE_ROWS = 65536  # rows per HDF5 chunk of the per-edge arrays


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


try:  # Intel ISA-L's deflate: standard deflate streams (any HDF5 reads them), 6-10x faster
    from isal import isal_zlib as _deflate  # than zlib on these floats, sizes within 3 %
except ImportError:  # pragma: no cover - isal is a dependency; zlib gives the same files' data
    import zlib as _deflate
DEFLATE_LEVEL = 1  # the level of every dataset lmjx writes in chunks (zlib's level 4 compressed
# q 1.5x slower than level 1 for 1 % less size)


class EdgeWriter:
    """Writes /edges of a map file piece by piece, in bounded memory: the states (q, qd, p,
    in HDF5 chunks of `STATE_ROWS` rows) and the per-edge arrays (`EDGE_ROWS` rows) are
    compressed with HDF5's own shuffle and deflate filters (readable by any HDF5 library)
    on all cores and written whole chunk by whole chunk as they fill; `offset` is computed
    from the lengths.  The caller's thread only slices and writes: every copy and all the
    compression happen in the pool."""

    def __init__(
        self, f: h5py.File, config: BundleConfig, reach: ReachResult, nq: int, threads: int | None = None
    ) -> None:
        from concurrent.futures import ThreadPoolExecutor

        g = f.create_group("edges", track_order=True)
        g.attrs["doc"] = (
            "Edge bundle (paper Algorithm 2): valid edges stored flat; edge e's states are rows "
            "offset[e] .. offset[e] + length[e] - 1 of q, qd and p."
        )
        _config_to_attrs(g, config)
        g.attrs["steps_max"] = config.steps
        self.group = g
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
                                       shuffle=True, track_times=False)  # fmt: skip
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
                job = self.pool.submit(_write_chunks, col.ds, group, col.rows_per_chunk, col.dtype)
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

    def __init__(self, ds: h5py.Dataset, rows_per_chunk: int) -> None:
        self.ds, self.rows_per_chunk = ds, rows_per_chunk
        self.dtype = ds.dtype  # kept: each h5py call waits for h5py's lock, held by the writing threads
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
        if out:
            self.ds.resize(self.written, axis=0)
        return out


GROUP = 4  # consecutive chunks of a dataset written by one job of EdgeWriter's pool


def _write_chunks(ds: h5py.Dataset, chunks: list[tuple[int, list[np.ndarray]]], rows: int, dtype: np.dtype) -> None:
    """Consecutive chunks (first row, pieces) of `ds`, assembled in one zero-padded block
    and shuffled at once, then compressed and written one by one."""
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
        ds.id.write_direct_chunk((row, *zeros), _deflate.compress(data, DEFLATE_LEVEL), 0)


def write_index(g: h5py.Group, reach: ReachResult, offset: np.ndarray, edges: np.ndarray | None) -> h5py.Dataset:
    """/edges/index: the CSR offsets, and the edge ids (`edges`, or left for the caller to
    fill into the returned dataset when None)."""
    idx = g.create_group("index", track_order=True)
    idx.attrs["doc"] = (
        "Edges over each reach cell (CSR): the edges of cell c = iy * nx + ix are "
        "edges[offset[c] : offset[c + 1]]; an edge is listed when its interaction point passes "
        "over the cell with the link's lowest surface at most `height` above the table."
    )
    idx.attrs["nx"] = len(reach.xs)
    idx.attrs["ny"] = len(reach.ys)
    idx.attrs["cell"] = reach.config.cell
    idx.attrs["height"] = float(g.attrs["index_height"])
    _dataset(idx, "offset", offset, "CSR offsets, length ny * nx + 1")
    if edges is not None:
        _dataset(idx, "edges", edges, "edge ids")
        return idx["edges"]
    total = int(offset[-1])
    ds = idx.create_dataset(
        "edges",
        shape=(total,),
        dtype=np.int32,
        chunks=(min(max(total, 1), 1 << 18),),
        compression="gzip",
        compression_opts=4,
        shuffle=True,
        track_times=False,
    )
    ds.attrs["doc"] = "edge ids"
    return ds


def _write_header(f: h5py.File, robot: Robot, failure: Failure, contents: str) -> None:
    f.attrs["schema"] = SCHEMA
    f.attrs["schema_version"] = SCHEMA_VERSION
    f.attrs["lmjx_version"] = __version__
    f.attrs["robot"] = robot.key if robot.key in ROBOTS else robot.name
    f.attrs["robot_model"] = robot.name
    f.attrs["robot_model_hash"] = robot.model_hash
    f.attrs["failure"] = failure.spec
    f.attrs["locked_joints"] = np.array([j for j, _ in failure.locked], dtype=np.int32)
    f.attrs["locked_angles"] = np.array([a for _, a in failure.locked], dtype=np.float64)
    f.attrs["contents"] = contents


LAZY_BYTES = 512 * 2**20  # edge states larger than this are read on demand (load_map's default)
CACHE_BYTES = 256 * 2**20  # HDF5 chunk cache per state dataset of a lazily opened map


@dataclass
class MapFile:
    """A validated map file: everything in memory, but for the edges' states of a lazily
    opened map (`lazy`), which stay in the file (kept open) and are read on demand."""

    path: Path
    attrs: dict
    failure: Failure
    reach: ReachResult | None
    edges: Bundle | None = None
    edges_attrs: dict = dataclasses.field(default_factory=dict)
    lazy: bool = False
    file: h5py.File | None = dataclasses.field(default=None, repr=False)
    robot: Robot | None = dataclasses.field(default=None, repr=False)  # the robot it was built for

    def __repr__(self) -> str:
        parts = [f"{self.robot.key if self.robot else '?'}", f"failure {self.failure.spec!r}"]
        if self.reach is not None:
            a = self.reach.areas()
            r = self.reach
            parts.append(f"reach {len(r.ys)} x {len(r.xs)} cells of {r.config.cell * 100:g} cm")
            parts.append(f"PM {a['pm']:.3f} m^2, NPM+PM {a['npm_pm']:.3f} m^2")
        if self.edges is not None:
            parts.append(f"{self.edges.n_edges:,} edges of {self.edges.sampled:,} sampled")
        lazy = ", lazy" if self.lazy else ""
        return f"MapFile({str(self.path)!r}: {'; '.join(parts)}{lazy})"

    def __enter__(self) -> MapFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self.edges is not None:
            for name in ("q", "qd", "p"):
                data = getattr(self.edges, name)
                if isinstance(data, StateReader):
                    data.close()
        if self.file is not None:
            self.file.close()
            self.file = None


def _attr_str(x: object) -> str:
    return x.decode() if isinstance(x, bytes) else str(x)


def file_robot(attrs: dict) -> str:
    """The robot a map or atlas file names: a shipped robot's name, or a user MJCF's model
    name (files from before robots were named: the Panda)."""
    return _attr_str(attrs.get("robot", "panda"))


def robot_for_file(path: Path, attrs: dict, robot: Robot | None) -> Robot:
    """The robot to read a file with: `robot` if it is the one the file was built for (else
    MapFileError), or, when None, the shipped robot the file names."""
    name = file_robot(attrs)
    if robot is None:
        if name not in ROBOTS:
            raise MapFileError(
                f"{path} was built for the robot '{name}' (a user's MJCF): pass --robot PATH to its file"
            )
        return load_robot(name)
    mine = robot.key if robot.key in ROBOTS else robot.name
    if name != mine and (name in ROBOTS or robot.key in ROBOTS):
        raise MapFileError(f"{path} was built for the robot '{name}', not '{mine}'; use --robot {name} or rebuild it")
    return robot


def load_map(
    path: str | Path, robot: Robot | str | Path | None = None, check_robot: bool = True, lazy: bool | None = None
) -> MapFile:
    """Open and validate a map file; raise MapFileError (one line) when it is unusable.
    `robot` (a Robot, a name or an MJCF's path): the robot to read it with, which must be
    the one it was built for; None: the shipped robot the file names.  A `with` block
    closes it (a lazily opened map keeps its file open until then).

    >>> import lmjx
    >>> with lmjx.load_map("maps/case2.h5") as m:   # written by `make run`
    ...     print(m.reach.areas()["pm"], m.edges.n_edges > 0)
    0.0 True

    The reach map, the per-edge arrays and the spatial index are read at once; the edge
    states (q, qd, p) too unless `lazy`: then they are read on demand from the file, which
    stays open (a map larger than memory is usable).  lazy=None: lazy when the states would
    take more than `LAZY_BYTES`.  Either way the map gives the same edges and decisions."""
    p = Path(path)
    robot = as_robot(robot) if robot is not None else None
    if not p.exists():
        raise MapFileError(f"map file {p} does not exist")
    if p.is_dir():
        raise MapFileError(f"{p} is a folder, not a map file")
    try:
        is_h5 = h5py.is_hdf5(str(p))
    except OSError as e:
        raise MapFileError(f"cannot read {p}: {e}") from None
    if not is_h5:
        raise MapFileError(f"{p} is not an HDF5 file (an lmjx map is HDF5)")
    try:
        f = h5py.File(p, "r", rdcc_nbytes=CACHE_BYTES, rdcc_nslots=100_003)
    except OSError as e:
        raise MapFileError(f"{p} is damaged or incomplete ({type(e).__name__}: {e}); rebuild the map") from None
    keep_open = False
    try:
        with f:
            attrs = {k: f.attrs[k] for k in f.attrs}
            if _attr_str(attrs.get("schema", "")) != SCHEMA:
                raise MapFileError(f"{p} is an HDF5 file but not an lmjx map (no schema='{SCHEMA}' attribute)")
            version = int(attrs.get("schema_version", -1))
            if version != SCHEMA_VERSION:
                rebuild = ""
                if version == 1 and "failure" in attrs:
                    robot_name = file_robot(attrs)
                    rebuild = (
                        f": its spatial index follows one interaction point, not the whole arm; rebuild it with "
                        f"lmjx build-map{'' if robot_name == 'panda' else f' --robot {robot_name}'} "
                        f'--failure "{_attr_str(attrs["failure"])}" --out {p}'
                    )
                raise MapFileError(
                    f"{p} has map schema version {version}; this lmjx ({__version__}) reads version {SCHEMA_VERSION}"
                    + rebuild
                )
            robot = robot_for_file(p, attrs, robot) if check_robot else (robot or load_robot(file_robot(attrs)))
            if check_robot and _attr_str(attrs.get("robot_model_hash", "")) != robot.model_hash:
                other = _attr_str(attrs.get("robot_model_hash", ""))[:12]
                raise MapFileError(
                    f"{p} was built for another version of the robot '{file_robot(attrs)}' (model hash {other}..., "
                    f"this lmjx has {robot.model_hash[:12]}...); rebuild the map"
                )
            locked = tuple(
                (int(j), float(a)) for j, a in zip(attrs["locked_joints"], attrs["locked_angles"], strict=True)
            )
            fail_name = _attr_str(attrs["failure"])
            failure = Failure(fail_name, locked, robot.nq)
            reach = _read_reach(f["reach"], failure, robot, attrs) if "reach" in f else None
            edges = None
            if "edges" in f:
                g = f["edges"]
                states_bytes = sum(g[k].size * g[k].dtype.itemsize for k in ("q", "qd", "p"))
                lazy = states_bytes > LAZY_BYTES if lazy is None else lazy
                edges = _read_edges(g, failure, lazy)
                keep_open = lazy
            edges_attrs = dict(f["edges"].attrs) if "edges" in f else {}
            if keep_open:  # the with block must not close it: reopen the handle it holds
                f = h5py.File(p, "r", rdcc_nbytes=CACHE_BYTES, rdcc_nslots=100_003)
                g = f["edges"]
                edges.q, edges.qd, edges.p = (StateReader(g[k]) for k in ("q", "qd", "p"))
    except MapFileError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise MapFileError(f"{p} is damaged or incomplete ({type(e).__name__}: {e}); rebuild the map") from None
    return MapFile(
        p, attrs, failure, reach, edges, edges_attrs, lazy=keep_open, file=f if keep_open else None, robot=robot
    )


def _config_to_attrs(g: h5py.Group, config: object) -> None:
    """Every field of a config dataclass as a group attribute (None as NaN)."""
    for f in dataclasses.fields(config):  # type: ignore[arg-type]
        v = getattr(config, f.name)
        if v is None:
            v = float("nan")
        if isinstance(v, tuple):
            v = np.array([str(x) for x in v], dtype=object) if v and isinstance(v[0], str) else np.array(v)
        g.attrs[f.name] = v


def _config_from_attrs(cls: type, a: dict):
    """Rebuild a config dataclass from group attributes, casting each field like its default."""
    values = {}
    for f in dataclasses.fields(cls):
        if f.name not in a:
            continue
        v = a[f.name]
        default = f.default
        if isinstance(v, float) and math.isnan(v):
            values[f.name] = None
        elif isinstance(default, tuple):
            values[f.name] = tuple(_attr_str(x) if isinstance(x, (str, bytes)) else float(x) for x in v)
        elif isinstance(default, bool):
            values[f.name] = bool(v)
        elif isinstance(default, int) or (default is None and float(v).is_integer()):
            values[f.name] = int(v)
        elif isinstance(default, str):
            values[f.name] = _attr_str(v)
        else:
            values[f.name] = float(v)
    return cls(**values)


def _read_reach(g: h5py.Group, failure: Failure, robot: Robot, root: dict) -> ReachResult:
    a = dict(g.attrs)
    return ReachResult(
        failure=failure,
        config=_config_from_attrs(ReachConfig, a),
        xs=g["x"][...],
        ys=g["y"][...],
        labels=g["labels"][...],
        labels_smooth=g["labels_smooth"][...],
        q=g["q"][...],
        attempt=g["attempt"][...],
        site=g["site"][...],
        target=g["target"][...],
        pos_err=g["pos_err"][...],
        seconds=float(a["seconds"]),
        compile_seconds=float(a["compile_seconds"]),
        kernel_seconds=float(a.get("kernel_seconds", float("nan"))),
        device=_attr_str(a["device"]),
        problems=int(a["problems"]),
        robot_hash=_attr_str(root["robot_model_hash"]),
        site_names=robot.site_names,
    )


def _read_edges(g: h5py.Group, failure: Failure, lazy: bool) -> Bundle:
    a = dict(g.attrs)
    offset = g["offset"][...]
    length = g["length"][...]
    q = g["q"] if lazy else g["q"][...]
    if len(offset) and int(offset[-1] + length[-1]) != len(q):
        raise MapFileError("the edge offsets do not match the stored states; rebuild the map")
    if "q_start" in g:
        q_start = g["q_start"][...]
    elif lazy:  # a map written before q_start was stored
        q_start = np.concatenate([q[o : o + 1] for o in offset]) if len(offset) else np.zeros((0, q.shape[1]))
    else:
        q_start = q[offset]
    return Bundle(
        config=_config_from_attrs(BundleConfig, a),
        failure=failure,
        offset=offset,
        length=length,
        q=q,
        qd=g["qd"] if lazy else g["qd"][...],
        p=g["p"] if lazy else g["p"][...],
        q_start=q_start.astype(np.float32),
        twist=g["twist"][...],
        duration=g["duration"][...],
        site=g["site"][...],
        start_cell=g["start_cell"][...],
        min_manipulability=g["min_manipulability"][...],
        peak_torque_ratio=g["peak_torque_ratio"][...],
        peak_velocity_ratio=g["peak_velocity_ratio"][...],
        peak_acceleration_ratio=g["peak_acceleration_ratio"][...],
        index_offset=g["index/offset"][...],
        index_edges=g["index/edges"][...],
        sampled=int(a["edges_sampled"]),
        rejected={k[len("rejected_") :]: int(v) for k, v in a.items() if k.startswith("rejected_")},
        seconds=float(a["seconds"]),
        compile_seconds=float(a["compile_seconds"]),
        rollout_seconds=float(a["rollout_seconds"]),
        edge_steps=int(a["edge_steps"]),
        states_evaluated=int(a["states_evaluated"]),
        device=_attr_str(a["device"]),
    )
