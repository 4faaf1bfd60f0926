"""HDF5 map files: writing (atomically) and reading with validation.

The schema is documented in maps/README.md for readers that do not import lmjx (plain
h5py, MATLAB, C++).  Version 1 holds the Reach-Ability map; later versions of this module
add groups without changing the existing ones.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from . import __version__
from .bundle import Bundle, BundleConfig
from .errors import MapFileError
from .failure import Failure
from .fileio import atomic_path
from .reach import ReachConfig, ReachResult
from .robot import Robot, load_robot

SCHEMA = "lmjx-map"
SCHEMA_VERSION = 1
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


def write_reach_map(path: str | Path, result: ReachResult, robot: Robot | None = None) -> None:
    """Write a map file holding only a Reach-Ability map; atomic (temp file, then rename)."""
    write_map(path, result, None, robot)


def write_map(path: str | Path, reach: ReachResult, bundle: Bundle | None, robot: Robot | None = None) -> dict:
    """Write a map file: the Reach-Ability map and, when given, the edge bundle.  Atomic
    (temp file, then rename).  Returns storage figures (bytes per stored edge state)."""
    robot = robot or load_robot()
    sizes: dict = {}
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w", track_order=True) as f:
            _write_header(f, robot, reach.failure, contents="reach" if bundle is None else "reach+edges")
            _write_robot(f, robot)
            _write_reach(f, reach)
            if bundle is not None:
                sizes = _write_edges(f, bundle, reach)
        if bundle is not None and len(bundle.q):
            sizes["file_bytes_per_state"] = Path(tmp).stat().st_size / len(bundle.q)
    return sizes


def _write_edges(f: h5py.File, b: Bundle, reach: ReachResult) -> dict:
    g = f.create_group("edges", track_order=True)
    g.attrs["doc"] = (
        "Edge bundle (paper Algorithm 2): valid edges stored flat; edge e's states are rows "
        "offset[e] .. offset[e] + length[e] - 1 of q, qd and p."
    )
    _config_to_attrs(g, b.config)
    g.attrs["steps_max"] = b.config.steps
    g.attrs["edges_sampled"] = b.sampled
    g.attrs["edges_valid"] = b.n_edges
    for reason, count in b.rejected.items():
        g.attrs[f"rejected_{reason}"] = count
    for k in ("seconds", "compile_seconds", "rollout_seconds"):
        g.attrs[k] = getattr(b, k)
    g.attrs["edge_steps"] = b.edge_steps
    g.attrs["states_evaluated"] = b.states_evaluated
    g.attrs["device"] = b.device
    per_state = {
        "q": (b.q, "joint angles J1..J7 at each state [rad] (locked joints at their angles)"),
        "qd": (b.qd, "joint velocities J1..J7 at each state [rad/s] (J^+ of the twist)"),
        "p": (b.p, "world position of the edge's interaction point at each state [m]"),
    }
    for name, (data, doc) in per_state.items():
        ds = g.create_dataset(
            name,
            data=data,
            chunks=(min(max(len(data), 1), 16384), data.shape[1]),
            compression="gzip",
            compression_opts=4,
            shuffle=True,
            track_times=False,
        )
        ds.attrs["doc"] = doc
    per_edge = {
        "offset": (b.offset, "first row of each edge in q, qd, p"),
        "length": (b.length, "states per edge (control steps + 1)"),
        "twist": (b.twist, "commanded twist of the interaction point: vx, vy, vz [m/s], wx, wy, wz [rad/s]"),
        "duration": (b.duration, "edge duration [s] = (length - 1) * dt"),
        "site": (b.site, "index into /robot/site_names of the edge's interaction point"),
        "start_cell": (b.start_cell, "(iy, ix) of the reach cell the edge starts from"),
        "min_manipulability": (b.min_manipulability, "smallest sqrt(det(J J^T)) along the edge"),
        "peak_torque_ratio": (b.peak_torque_ratio, "max |tau_i| / tau_max_i over free joints and states"),
        "peak_velocity_ratio": (b.peak_velocity_ratio, "max |qd_i| / qd_max_i"),
        "peak_acceleration_ratio": (b.peak_acceleration_ratio, "max |qdd_i| / qdd_max_i"),
    }
    for name, (data, doc) in per_edge.items():
        _dataset(g, name, data, doc)
    idx = g.create_group("index", track_order=True)
    idx.attrs["doc"] = (
        "Edges over each reach cell (CSR): the edges of cell c = iy * nx + ix are "
        "edges[offset[c] : offset[c + 1]]; an edge is listed when its interaction point passes "
        "over the cell with the link's lowest surface at most `height` above the table."
    )
    idx.attrs["nx"] = len(reach.xs)
    idx.attrs["ny"] = len(reach.ys)
    idx.attrs["cell"] = reach.config.cell
    idx.attrs["height"] = b.config.index_height
    _dataset(idx, "offset", b.index_offset, "CSR offsets, length ny * nx + 1")
    _dataset(idx, "edges", b.index_edges, "edge ids")
    n_states = max(len(b.q), 1)
    stored = sum(g[k].id.get_storage_size() for k in ("q", "qd", "p"))
    raw = sum(np.asarray(g[k]).nbytes for k in ("q", "qd", "p"))
    g.attrs["bytes_per_state"] = stored / n_states
    g.attrs["raw_bytes_per_state"] = raw / n_states
    return {"bytes_per_state": stored / n_states, "raw_bytes_per_state": raw / n_states}


def _write_header(f: h5py.File, robot: Robot, failure: Failure, contents: str) -> None:
    f.attrs["schema"] = SCHEMA
    f.attrs["schema_version"] = SCHEMA_VERSION
    f.attrs["lmjx_version"] = __version__
    f.attrs["robot_model"] = robot.name
    f.attrs["robot_model_hash"] = robot.model_hash
    f.attrs["failure"] = failure.spec
    f.attrs["locked_joints"] = np.array([j for j, _ in failure.locked], dtype=np.int32)
    f.attrs["locked_angles"] = np.array([a for _, a in failure.locked], dtype=np.float64)
    f.attrs["contents"] = contents


@dataclass
class MapFile:
    """A validated map file, read into memory."""

    path: Path
    attrs: dict
    failure: Failure
    reach: ReachResult | None
    edges: Bundle | None = None
    edges_attrs: dict = dataclasses.field(default_factory=dict)


def _attr_str(x: object) -> str:
    return x.decode() if isinstance(x, bytes) else str(x)


def load_map(path: str | Path, robot: Robot | None = None, check_robot: bool = True) -> MapFile:
    """Open and validate a map file; raise MapFileError (one line) when it is unusable."""
    p = Path(path)
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
    robot = robot or load_robot()
    try:
        with h5py.File(p, "r") as f:
            attrs = {k: f.attrs[k] for k in f.attrs}
            if _attr_str(attrs.get("schema", "")) != SCHEMA:
                raise MapFileError(f"{p} is an HDF5 file but not an lmjx map (no schema='{SCHEMA}' attribute)")
            version = int(attrs.get("schema_version", -1))
            if version != SCHEMA_VERSION:
                raise MapFileError(
                    f"{p} has map schema version {version}; this lmjx ({__version__}) reads version {SCHEMA_VERSION}"
                )
            if check_robot and _attr_str(attrs.get("robot_model_hash", "")) != robot.model_hash:
                other = _attr_str(attrs.get("robot_model_hash", ""))[:12]
                raise MapFileError(
                    f"{p} was built for another robot model (hash {other}..., "
                    f"this lmjx has {robot.model_hash[:12]}...); rebuild the map"
                )
            locked = tuple(
                (int(j), float(a)) for j, a in zip(attrs["locked_joints"], attrs["locked_angles"], strict=True)
            )
            fail_name = _attr_str(attrs["failure"])
            failure = Failure(fail_name, locked)
            reach = _read_reach(f["reach"], failure, robot, attrs) if "reach" in f else None
            edges = _read_edges(f["edges"], failure) if "edges" in f else None
            edges_attrs = dict(f["edges"].attrs) if "edges" in f else {}
    except MapFileError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise MapFileError(f"{p} is damaged or incomplete ({type(e).__name__}: {e}); rebuild the map") from None
    return MapFile(p, attrs, failure, reach, edges, edges_attrs)


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


def _read_edges(g: h5py.Group, failure: Failure) -> Bundle:
    a = dict(g.attrs)
    offset = g["offset"][...]
    length = g["length"][...]
    q = g["q"][...]
    if len(offset) and int(offset[-1] + length[-1]) != len(q):
        raise MapFileError("the edge offsets do not match the stored states; rebuild the map")
    return Bundle(
        config=_config_from_attrs(BundleConfig, a),
        failure=failure,
        offset=offset,
        length=length,
        q=q,
        qd=g["qd"][...],
        p=g["p"][...],
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
