"""A map's edges for other tools: the edges that act over a region of the table (the map's
own, and with `turned` their copies turned about the arm's base joint, as lmjx's planner
offers them), one edge's states with their time stamps (`Edge`, turned or not), and a joint
trajectory exported to files a robot's controller reads without lmjx (`Trajectory`: CSV, or
JSON laid out as a ROS `trajectory_msgs/JointTrajectory`).

An edge's states are those of Algorithm 2's rollout: q_{k+1} = q_k + qd_k dt, so between two
states the joints move in a straight line at qd_k.  `edge_trajectory` resamples exactly that:
positions interpolated linearly, every stored state a sample where the new period divides
the map's.  A point's velocity is the one that carries the arm in a straight line to the
next point (where the period divides the map's: the interval's qd_k, to the map's float32
rounding, about 1e-5 rad/s): a controller that integrates the velocities arrives at every
point, not a rounding error per state away from it; a point's acceleration likewise carries
its velocity to the next point's.  A whole action, from rest to rest, is exported by
`lmjx.toolkit.trajectory` into the same `Trajectory`.  Nothing here plans or simulates.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lmjx.errors import ConfigError
from lmjx.runtime.fileio import check_writable, write_text_atomic

if TYPE_CHECKING:
    from lmjx.mapfile.bundle import Bundle
    from lmjx.mapfile.turned import TurnAxis
    from lmjx.model.failure import Failure
    from lmjx.model.robot import Robot
    from lmjx.reach.reachability import ReachResult

NS = 1_000_000_000  # nanoseconds in a second (a JointTrajectory's time_from_start: sec, nanosec)


def _region(region: object) -> tuple[float, float, float, float]:
    """(xmin, ymin, xmax, ymax) [m] as floats, checked (ConfigError in one line)."""
    if isinstance(region, str | bytes) or not hasattr(region, "__len__") or len(region) != 4:  # type: ignore[arg-type]
        raise ConfigError(f"a region is (xmin, ymin, xmax, ymax) in metres, got {region!r}")
    try:
        xmin, ymin, xmax, ymax = (float(v) for v in region)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise ConfigError(f"a region is (xmin, ymin, xmax, ymax) in metres, got {region!r}") from None
    if not all(math.isfinite(v) for v in (xmin, ymin, xmax, ymax)) or xmin > xmax or ymin > ymax:
        raise ConfigError(f"a region is (xmin, ymin, xmax, ymax) with xmin <= xmax and ymin <= ymax, got {region!r}")
    return xmin, ymin, xmax, ymax


def edges_in_region(bundle: Bundle, reach: ReachResult, region: tuple[float, float, float, float]) -> np.ndarray:
    """Ids (sorted, unique) of the edges during which the whole arm can act on an object in
    the axis-aligned rectangle `region` = (xmin, ymin, xmax, ymax) [m] of the table: those the
    map's spatial index lists for any reach cell whose square overlaps the rectangle."""
    xmin, ymin, xmax, ymax = _region(region)
    half = reach.config.cell / 2
    ix = np.nonzero((reach.xs + half >= xmin) & (reach.xs - half <= xmax))[0]
    iy = np.nonzero((reach.ys + half >= ymin) & (reach.ys - half <= ymax))[0]
    nx = len(reach.xs)
    found = [bundle.edges_over(int(y), int(x), nx) for y in iy for x in ix]
    return np.unique(np.concatenate(found)).astype(np.int64) if found else np.zeros(0, np.int64)


def turned_in_region(
    bundle: Bundle, reach: ReachResult, robot: Robot, failure: Failure, region: tuple[float, float, float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """The edges over `region` as lmjx's planner offers them over a target: (ids (K,) int64,
    turns (K,) float64 [rad of the base joint]): the map's own (`edges_in_region`, turn 0),
    then the copies of the map's edges turned about the arm's base joint
    (`lmjx.mapfile.turned.turned_over_target`, sorted by edge then turn) for an object at
    the region's centre whose square, grown by the planner's margin, is the region (its half
    size: the larger of the region's half width and half depth).  No copies where the arm has
    no free base joint with a vertical axis."""
    from lmjx.mapfile.turned import turned_over_target

    own = edges_in_region(bundle, reach, region)
    xmin, ymin, xmax, ymax = _region(region)
    centre = np.array([(xmin + xmax) / 2, (ymin + ymax) / 2])
    half = max(xmax - xmin, ymax - ymin) / 2
    ids, turns = turned_over_target(bundle, reach, robot, failure, centre, half, 0.0)
    return np.concatenate([own, ids]).astype(np.int64), np.concatenate([np.zeros(len(own)), turns])


@dataclass(frozen=True, eq=False)
class Edge:
    """One edge of a map (`MapFile.edge`): its states, dt apart, as the map stores them
    (float32 values, here as float64), turned about the arm's base joint by `turn` (0: as
    stored).  Arrays: q, qd (T, nq), t (T,), p (T, 3)."""

    index: int  # its id in the map
    q: np.ndarray = field(repr=False)  # (T, nq) joint angles [rad], locked joints at their angles
    qd: np.ndarray = field(repr=False)  # (T, nq) joint velocities [rad/s]
    t: np.ndarray = field(repr=False)  # (T,) time from the edge's start [s]
    p: np.ndarray = field(repr=False)  # (T, 3) the interaction point's position on its path [m], world frame
    point: str  # the interaction point that follows the twist ("hand", "wrist", "forearm", ...)
    joints: tuple[str, ...]  # the robot's joint names (its MJCF's), the columns of q and qd
    twist: tuple[float, ...]  # the commanded twist: linear [m/s] then angular [rad/s] velocity
    source: Any = field(default=None, repr=False)  # the MapFile it came from (for `lmjx.transit`)
    turn: float = 0.0  # [rad] the base joint turned by this in every state (`MapFile.edge(i, turn=...)`)

    @property
    def dt(self) -> float:
        """The period of its states [s]."""
        return float(self.t[1] - self.t[0]) if len(self.t) > 1 else 0.0

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def __repr__(self) -> str:
        turned = f" turned {self.turn:+.4f} rad" if self.turn else ""
        return (f"Edge({self.index}{turned}: {len(self.t)} states over {self.duration:.2f} s, point {self.point}, "
                f"from ({self.p[0, 0]:.3f}, {self.p[0, 1]:.3f}, {self.p[0, 2]:.3f}) m)")  # fmt: skip


def read_edge(
    bundle: Bundle,
    index: int,
    joints: tuple[str, ...],
    sites: tuple[str, ...],
    source: Any,
    turn: float = 0.0,
    axis: TurnAxis | None = None,
    limits: tuple[float, float] = (-math.inf, math.inf),
) -> Edge:
    """Edge `index` of `bundle` (`joints`: the robot's joint names; `sites`: its site names),
    turned by `turn` [rad] about the base joint `axis` (`lmjx.mapfile.turned.TurnedEdges`:
    the states lmjx's planner executes for that turn), whose `limits` (lower, upper) [rad]
    every turned state must keep within."""
    n = bundle.n_edges
    if isinstance(index, bool) or not isinstance(index, int | np.integer) or not 0 <= int(index) < n:
        raise ConfigError(f"edge {index!r} does not exist; the map has {n:,} edges (0 to {n - 1:,})")
    if not is_number(turn) or not math.isfinite(turn):
        raise ConfigError(f"a turn is a finite number of radians of the base joint, got {turn!r}")
    i, turn = int(index), float(turn)
    if turn == 0.0:
        s = bundle.edge(i)
    else:
        from lmjx.mapfile.turned import TurnedEdges

        if axis is None:
            raise ConfigError("this map's arm has no free base joint with a vertical axis: its edges are not turned; "
                              "give turn=0")  # fmt: skip
        s = TurnedEdges(bundle, np.array([i]), np.array([turn]), axis).edge(0)
        base = np.asarray(bundle.edge(i, ("q",))["q"][:, axis.joint], np.float64)
        low, high = float(base.min()) + turn, float(base.max()) + turn
        if low < limits[0] or high > limits[1]:  # (the test `turned_over_target` makes)
            name = joints[axis.joint]
            raise ConfigError(
                f"edge {i} turned by {turn:+.4f} rad takes {name} to [{low:.4f}, {high:.4f}] rad, past its limits "
                f"[{limits[0]:.4f}, {limits[1]:.4f}]; this edge turns by {limits[0] - base.min():+.4f} to "
                f"{limits[1] - base.max():+.4f} rad"
            )
    steps = len(s["q"])
    site = sites[int(bundle.site[i])]
    return Edge(
        index=i,
        q=np.asarray(s["q"], np.float64),
        qd=np.asarray(s["qd"], np.float64),
        t=np.arange(steps) * float(bundle.config.dt),
        p=np.asarray(s["p"], np.float64),
        point=site.removeprefix("ip_"),
        joints=tuple(joints),
        twist=tuple(float(v) for v in bundle.twist[i]),
        source=source,
        turn=turn,
    )


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A time-stamped joint trajectory: positions q (N, nq) [rad], velocities qd (N, nq)
    [rad/s] and accelerations qdd (N, nq) [rad/s^2] at times t (N,) [s] from its start, for
    the joints `joints` (in that order)."""

    t: np.ndarray = field(repr=False)
    q: np.ndarray = field(repr=False)
    qd: np.ndarray = field(repr=False)
    qdd: np.ndarray = field(repr=False)
    joints: tuple[str, ...]
    edge: int | None = None  # the map's edge it follows, if any
    point: str = ""  # that edge's interaction point
    turn: float = 0.0  # [rad] that edge turned about the base joint by this
    at_rest: bool = False  # it starts and ends at rest (a whole action); False: an edge at its own speed

    def __repr__(self) -> str:
        turned = f" turned {self.turn:+.4f} rad" if self.turn else ""
        what = "" if self.edge is None else f"; edge {self.edge}{turned}"
        rest = "; from rest to rest" if self.at_rest else ""
        return f"Trajectory({len(self.t)} points over {float(self.t[-1]):.3f} s, {len(self.joints)} joints{what}{rest})"

    def csv_text(self) -> str:
        """One row per point: time_from_start [s], then each joint's position [rad] (columns
        named by the joints), then each joint's velocity [rad/s] (`<joint>_velocity`), then
        its acceleration [rad/s^2] (`<joint>_acceleration`); every value in the shortest form
        that reads back exactly."""
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["time_from_start", *self.joints, *(f"{j}_velocity" for j in self.joints),
                    *(f"{j}_acceleration" for j in self.joints)])  # fmt: skip
        for t, q, qd, qdd in zip(self.t, self.q, self.qd, self.qdd, strict=True):
            w.writerow([repr(float(t)), *(repr(float(v)) for v in (*q, *qd, *qdd))])
        return buf.getvalue()

    def json_data(self) -> dict:
        """A ROS trajectory_msgs/JointTrajectory message, field for field (a ROS 2 node fills
        the message from it with rosidl_runtime_py.set_message_fields): header, joint_names,
        and points each with positions, velocities, accelerations, effort (empty) and
        time_from_start as {"sec", "nanosec"} (whole nanoseconds)."""
        return {
            "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""},
            "joint_names": list(self.joints),
            "points": [
                {
                    "positions": [float(v) for v in q],
                    "velocities": [float(v) for v in qd],
                    "accelerations": [float(v) for v in qdd],
                    "effort": [],
                    "time_from_start": ros_duration(float(t)),
                }
                for t, q, qd, qdd in zip(self.t, self.q, self.qd, self.qdd, strict=True)
            ],
        }

    def write(self, path: str | Path) -> Path:
        """Write it to `path` (atomically): CSV for a name ending in .csv, JSON for .json."""
        if not isinstance(path, str | Path):
            raise ConfigError(f"a trajectory's file is a path ending in .csv or .json, got {path!r}")
        p = Path(path)
        if p.suffix.lower() not in (".csv", ".json"):
            raise ConfigError(f"{p}: a trajectory is written as .csv or .json; give a name ending in one of them")
        check_writable(p, "trajectory")
        text = self.csv_text() if p.suffix.lower() == ".csv" else json.dumps(self.json_data(), indent=1) + "\n"
        write_text_atomic(p, text)
        return p

    @staticmethod
    def read(path: str | Path) -> Trajectory:
        """A trajectory `write` wrote (.csv or .json), read back: its times (JSON: to the
        nanosecond), positions, velocities, accelerations and joint names."""
        p = Path(path)
        try:
            text = p.read_text()
        except OSError as e:
            raise ConfigError(f"cannot read the trajectory {p}: {e.strerror}") from None
        try:
            if p.suffix.lower() == ".json":
                msg = json.loads(text)
                pts = msg["points"]
                t = np.array([x["time_from_start"]["sec"] + x["time_from_start"]["nanosec"] / NS for x in pts])
                cols = [np.array([x[k] for x in pts], np.float64) for k in ("positions", "velocities", "accelerations")]
                joints = tuple(msg["joint_names"])
            else:
                rows = list(csv.reader(io.StringIO(text)))
                nj = (len(rows[0]) - 1) // 3
                table = np.array(rows[1:], np.float64)
                t, joints = table[:, 0], tuple(rows[0][1 : 1 + nj])
                cols = [table[:, 1 + k * nj : 1 + (k + 1) * nj] for k in range(3)]
        except (KeyError, TypeError, ValueError, IndexError, json.JSONDecodeError) as e:
            raise ConfigError(f"{p} is not a trajectory lmjx wrote ({type(e).__name__}: {e})") from None
        return Trajectory(t, *cols, joints)


def ros_duration(t: float) -> dict[str, int]:
    """A time [s] >= 0 as a ROS builtin_interfaces/Duration: whole seconds and nanoseconds."""
    ns = round(t * NS)
    return {"sec": ns // NS, "nanosec": ns % NS}


def sample_times(end: float, step: float) -> np.ndarray:
    """Times 0, step, 2 step, ... up to `end` [s], and `end` itself where step does not divide it."""
    n = math.floor(end / step + 1e-9)
    times = np.arange(n + 1) * float(step)
    if end - times[-1] > 1e-9 * max(1.0, end):
        times = np.append(times, end)
    times[-1] = min(times[-1], end)
    return times


def is_number(x: object) -> bool:
    """Whether `x` is a real number (a Python or numpy int or float; not a bool)."""
    return not isinstance(x, bool | np.bool_) and isinstance(x, int | float | np.integer | np.floating)


def check_period(dt: object) -> None:
    """A sampling period: a number of seconds above 0 (ConfigError in one line)."""
    if not is_number(dt) or not (math.isfinite(dt) and dt > 0):  # type: ignore[operator]
        raise ConfigError(f"dt must be a number of seconds above 0, got {dt!r}")


def joint_order(have: tuple[str, ...], names: object, what: str) -> np.ndarray:
    """The columns (len(have),) that put joints `have` in the order of `names` (the user's,
    e.g. a controller's), checked: the same joints, each once (ConfigError in one line)."""
    if isinstance(names, str) or not isinstance(names, list | tuple) or not all(isinstance(n, str) for n in names):
        raise ConfigError(f"joint_names: give a list of joint names, got {names!r}")
    missing = [n for n in have if n not in names]
    unknown = [n for n in names if n not in have]
    if missing or unknown or len(set(names)) != len(names):
        parts = [f"missing {missing}" if missing else "", f"not {what}'s {unknown}" if unknown else "",
                 "a name twice" if len(set(names)) != len(names) else ""]  # fmt: skip
        raise ConfigError(f"joint_names do not match {what}'s joints {list(have)}: {'; '.join(x for x in parts if x)}")
    return np.array([have.index(n) for n in names])


def edge_trajectory(edge: Edge, dt: float | None = None) -> Trajectory:
    """Edge `edge`'s joint trajectory sampled every `dt` seconds (default: its own period),
    from its start to its end at the edge's own speed (the last sample at the end even
    where `dt` does not divide the duration): positions interpolated linearly between the
    stored states, the motion Algorithm 2 integrated (q_{k+1} = q_k + qd_k dt); each point's
    velocity the one that carries the arm straight to the next point (the last: the last
    state's velocity), each point's acceleration the one that carries its velocity to the
    next point's (the last: 0).  Its states are samples wherever `dt` divides the map's
    period."""
    check_period(edge.dt if dt is None else dt)
    step = float(edge.dt if dt is None else dt)
    end = edge.duration
    times = sample_times(end, step)
    meta = dict(edge=edge.index, point=edge.point, turn=edge.turn)
    if len(edge.t) < 2:
        zero = np.zeros_like(edge.q[:1])
        return Trajectory(np.zeros(1), edge.q[:1].copy(), edge.qd[:1].copy(), zero, edge.joints, **meta)
    period = edge.dt
    k = np.minimum(np.floor(times / period + 1e-9).astype(np.int64), len(edge.t) - 1)  # the interval each lies in
    into = np.clip(times - k * period, 0.0, None)[:, None]
    within = k < len(edge.t) - 1
    slope = np.diff(edge.q, axis=0) / period  # (T - 1, nq) each interval's velocity
    q = edge.q[k].copy()
    q[within] += slope[k[within]] * into[within]
    gaps = np.diff(times)[:, None]
    qd = np.concatenate([np.diff(q, axis=0) / gaps, edge.qd[-1:]])
    qdd = np.concatenate([np.diff(qd, axis=0) / gaps, np.zeros_like(qd[:1])])
    return Trajectory(times, q, qd, qdd, edge.joints, **meta)


def in_joint_order(traj: Trajectory, joint_names: object, what: str) -> Trajectory:
    """`traj` with its columns in the order of `joint_names` (None: as it is), checked against its joints."""
    if joint_names is None:
        return traj
    cols = joint_order(traj.joints, joint_names, what)
    return replace(traj, q=traj.q[:, cols], qd=traj.qd[:, cols], qdd=traj.qdd[:, cols],
                   joints=tuple(traj.joints[c] for c in cols))  # fmt: skip
