"""Reading map files with validation: `load_map` opens one (in memory, or lazily with the
edges' states left in the file) and raises `MapFileError` in one line when it is unusable.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np

from lmjx import __version__
from lmjx.errors import ConfigError, MapFileError
from lmjx.mapfile.bundle import Bundle, BundleConfig
from lmjx.mapfile.h5 import h5open
from lmjx.mapfile.lazystates import StateReader, damaged
from lmjx.mapfile.openable import check_map_path
from lmjx.mapfile.pushcounts import read_push_counts
from lmjx.mapfile.schema import READ_VERSIONS, SCHEMA, SCHEMA_VERSION, attr_str, config_from_attrs, file_robot
from lmjx.model.failure import Failure
from lmjx.model.robot import ROBOTS, Robot, as_robot, load_robot
from lmjx.reach.reachability import ReachConfig, ReachResult

if TYPE_CHECKING:
    from lmjx.mapfile.trajectory import Edge
    from lmjx.mapfile.turned import TurnAxis

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
    _axis: tuple[TurnAxis | None] | None = dataclasses.field(default=None, init=False, repr=False)  # `turn_axis`'s

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

    def edges_over(
        self, region: tuple[float, float, float, float], turned: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Ids (sorted) of the edges during which the whole arm can act on an object in the
        axis-aligned rectangle `region` = (xmin, ymin, xmax, ymax) [m] of the table top (robot
        base frame): the spatial index's edges of every reach cell whose square overlaps it.

        `turned`: also the copies of the map's edges turned about the arm's free base joint
        that lmjx's planner offers for an object at the region's centre whose square, grown by
        its margin, is the region: (ids (K,), turns (K,) [rad of the base joint]), the map's
        own edges first (turn 0, sorted), then the copies (sorted by edge, then turn; whole
        degrees, at most 4 turns an edge, each within the joint's limits over the whole edge,
        none starting with its interaction point within 8 cm of the centre).  Pass an id and
        its turn on to `edge(i, turn=...)`.  No copies where the arm's base joint is locked
        or its axis is not vertical."""
        from lmjx.mapfile.trajectory import edges_in_region, turned_in_region

        if not isinstance(turned, bool | np.bool_):
            raise ConfigError(f"edges_over: turned is True or False, got {turned!r}")
        if not turned:
            return edges_in_region(self._bundle(), self.reach, region)
        assert self.robot is not None
        return turned_in_region(self._bundle(), self.reach, self.robot, self.failure, region)

    def edge(self, index: int, turn: float = 0.0) -> Edge:
        """Edge `index`: its joint states q, qd (T, nq), time stamps t (T,) and the interaction
        point's path p (T, 3) (`lmjx.mapfile.trajectory.Edge`), turned about the arm's base
        joint by `turn` [rad] (as `edges_over(region, turned=True)` gives them; 0: as stored):
        that joint `turn` more in every state, qd unchanged, the point's path turned about
        the joint's axis, the states lmjx's planner executes for that turn.  A turn that takes
        the joint past its limits anywhere along the edge is refused (ConfigError)."""
        from lmjx.mapfile.trajectory import read_edge

        assert self.robot is not None
        bundle = self._bundle()
        axis, limits = None, (-np.inf, np.inf)
        if turn is not None and not isinstance(turn, bool) and isinstance(turn, int | float | np.number) and turn != 0:
            axis = self.turn_axis()
            if axis is not None:
                limits = (float(self.robot.lower[axis.joint]), float(self.robot.upper[axis.joint]))
        return read_edge(bundle, index, self.robot.joint_names, self.robot.site_names, self, turn, axis, limits)

    def turn_axis(self) -> TurnAxis | None:
        """The arm's base joint edges turn about (`lmjx.mapfile.turned.turn_axis`), or None."""
        from lmjx.mapfile.turned import turn_axis

        assert self.robot is not None
        if self._axis is None:
            self._axis = (turn_axis(self.robot, self.failure),)
        return self._axis[0]

    def _bundle(self) -> Bundle:
        if self.edges is None or self.reach is None:
            extra = "" if self.robot is None or self.robot.key == "panda" else f" --robot {self.robot.key}"
            raise MapFileError(
                f"{self.path} has no edges; build it with: lmjx build-map{extra} --failure {self.failure.spec}"
            )
        return self.edges

    def close(self) -> None:
        if self.edges is not None:
            for name in ("q", "qd", "p"):
                data = getattr(self.edges, name)
                if isinstance(data, StateReader):
                    data.close()
        if self.file is not None:
            self.file.close()
            self.file = None


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
    path: str | Path,
    robot: Robot | str | Path | None = None,
    check_robot: bool = True,
    lazy: bool | None = None,
    with_edges: bool = True,
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
    take more than `LAZY_BYTES`.  Either way the map gives the same edges and decisions.
    `with_edges=False`: the reach map alone (the edges' group, whose spatial index a large
    map holds in hundreds of MB, is not read: `edges` is None and `edges_attrs` empty even
    where the file holds edges, and `lazy` does not apply)."""
    p = check_map_path(path)
    robot = as_robot(robot) if robot is not None else None
    try:
        f = h5open(p, "r", rdcc_nbytes=CACHE_BYTES, rdcc_nslots=100_003)
    except OSError as e:
        raise MapFileError(f"{p} is damaged or incomplete ({type(e).__name__}: {e}); rebuild the map") from None
    keep_open = False
    try:
        with f:
            attrs = {k: f.attrs[k] for k in f.attrs}
            if attr_str(attrs.get("schema", "")) != SCHEMA:
                raise MapFileError(f"{p} is an HDF5 file but not an lmjx map (no schema='{SCHEMA}' attribute)")
            version = int(attrs.get("schema_version", -1))
            if version not in READ_VERSIONS:
                rebuild = ""
                if version == 1 and "failure" in attrs:
                    robot_name = file_robot(attrs)
                    rebuild = (
                        f": its spatial index follows one interaction point, not the whole arm; rebuild it with "
                        f"lmjx build-map{'' if robot_name == 'panda' else f' --robot {robot_name}'} "
                        f'--failure "{attr_str(attrs["failure"])}" --out {p}'
                    )
                raise MapFileError(
                    f"{p} has map schema version {version}; this lmjx ({__version__}) reads versions "
                    f"{READ_VERSIONS[0]} to {SCHEMA_VERSION}" + rebuild
                )
            robot = robot_for_file(p, attrs, robot) if check_robot else (robot or load_robot(file_robot(attrs)))
            if check_robot and attr_str(attrs.get("robot_model_hash", "")) != robot.model_hash:
                other = attr_str(attrs.get("robot_model_hash", ""))[:12]
                raise MapFileError(
                    f"{p} was built for another version of the robot '{file_robot(attrs)}' (model hash {other}..., "
                    f"this lmjx has {robot.model_hash[:12]}...); rebuild the map"
                )
            locked = tuple(
                (int(j), float(a)) for j, a in zip(attrs["locked_joints"], attrs["locked_angles"], strict=True)
            )
            fail_name = attr_str(attrs["failure"])
            failure = Failure(fail_name, locked, robot.nq)
            reach = _read_reach(f["reach"], failure, robot, attrs) if "reach" in f else None
            edges = None
            if "edges" in f and with_edges:
                g = f["edges"]
                states_bytes = sum(g[k].size * g[k].dtype.itemsize for k in ("q", "qd", "p"))
                lazy = states_bytes > LAZY_BYTES if lazy is None else lazy
                edges = _read_edges(g, failure, lazy)
                keep_open = lazy
            edges_attrs = dict(f["edges"].attrs) if "edges" in f and with_edges else {}
            if keep_open:  # the with block must not close it: reopen the handle it holds
                f = h5open(p, "r", rdcc_nbytes=CACHE_BYTES, rdcc_nslots=100_003)
                g = f["edges"]
                edges.q, edges.qd, edges.p = (StateReader(g[k]) for k in ("q", "qd", "p"))
    except MapFileError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise MapFileError(f"{p} is damaged or incomplete ({type(e).__name__}: {e}); rebuild the map") from None
    return MapFile(
        p, attrs, failure, reach, edges, edges_attrs, lazy=keep_open, file=f if keep_open else None, robot=robot
    )


def _values(ds: h5py.Dataset) -> np.ndarray:
    """A dataset's values; a part HDF5 cannot read back (a chunk whose checksum fails, ...)
    is a one-line MapFileError naming the dataset."""
    try:
        return ds[...]
    except OSError as e:
        raise damaged(ds, "a chunk HDF5 cannot read back", str(e).splitlines()[0] if str(e) else "unreadable") from None


def _read_reach(g: h5py.Group, failure: Failure, robot: Robot, root: dict) -> ReachResult:
    a = dict(g.attrs)
    return ReachResult(
        failure=failure,
        config=config_from_attrs(ReachConfig, a),
        xs=_values(g["x"]),
        ys=_values(g["y"]),
        labels=_values(g["labels"]),
        labels_smooth=_values(g["labels_smooth"]),
        q=_values(g["q"]),
        attempt=_values(g["attempt"]),
        site=_values(g["site"]),
        target=_values(g["target"]),
        pos_err=_values(g["pos_err"]),
        seconds=float(a["seconds"]),
        compile_seconds=float(a["compile_seconds"]),
        kernel_seconds=float(a.get("kernel_seconds", float("nan"))),
        device=attr_str(a["device"]),
        problems=int(a["problems"]),
        robot_hash=attr_str(root["robot_model_hash"]),
        site_names=robot.site_names,
    )


def _read_edges(g: h5py.Group, failure: Failure, lazy: bool) -> Bundle:
    a = dict(g.attrs)
    offset = _values(g["offset"])
    length = _values(g["length"])
    q = g["q"] if lazy else _values(g["q"])
    if len(offset) and int(offset[-1] + length[-1]) != len(q):
        raise MapFileError("the edge offsets do not match the stored states; rebuild the map")
    if "q_start" in g:
        q_start = _values(g["q_start"])
    elif lazy:  # a map written before q_start was stored
        q_start = np.concatenate([q[o : o + 1] for o in offset]) if len(offset) else np.zeros((0, q.shape[1]))
    else:
        q_start = q[offset]
    return Bundle(
        config=config_from_attrs(BundleConfig, a),
        failure=failure,
        offset=offset,
        length=length,
        q=q,
        qd=g["qd"] if lazy else _values(g["qd"]),
        p=g["p"] if lazy else _values(g["p"]),
        q_start=q_start.astype(np.float32),
        twist=_values(g["twist"]),
        duration=_values(g["duration"]),
        site=_values(g["site"]),
        start_cell=_values(g["start_cell"]),
        min_manipulability=_values(g["min_manipulability"]),
        peak_torque_ratio=_values(g["peak_torque_ratio"]),
        peak_velocity_ratio=_values(g["peak_velocity_ratio"]),
        peak_acceleration_ratio=_values(g["peak_acceleration_ratio"]),
        index_offset=_values(g["index/offset"]),
        index_edges=_values(g["index/edges"]),
        sampled=int(a["edges_sampled"]),
        rejected={k[len("rejected_") :]: int(v) for k, v in a.items() if k.startswith("rejected_")},
        seconds=float(a["seconds"]),
        compile_seconds=float(a["compile_seconds"]),
        rollout_seconds=float(a["rollout_seconds"]),
        edge_steps=int(a["edge_steps"]),
        states_evaluated=int(a["states_evaluated"]),
        device=attr_str(a["device"]),
        push=read_push_counts(g),
    )
