"""A map's edges for other tools: the edges that act over a region of the table, one edge's
states with their time stamps (`Edge`), and its joint trajectory resampled and exported to
files a robot's controller reads without lmjx (`Trajectory`: CSV, or JSON laid out as a
ROS `trajectory_msgs/JointTrajectory`).

An edge's states are those of Algorithm 2's rollout: q_{k+1} = q_k + qd_k dt, so between two
states the joints move in a straight line at qd_k.  `trajectory` resamples exactly that:
positions interpolated linearly, every stored state a sample where the new period divides
the map's.  A point's velocity is the one that carries the arm in a straight line to the
next point (where the period divides the map's: the interval's qd_k, to the map's float32
rounding, about 1e-5 rad/s): a controller that integrates the velocities arrives at every
point, not a rounding error per state away from it.  Nothing here plans or simulates.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lmjx.errors import ConfigError
from lmjx.runtime.fileio import check_writable, write_text_atomic

if TYPE_CHECKING:
    from lmjx.mapfile.bundle import Bundle
    from lmjx.reach.reachability import ReachResult

TRAJECTORY_FORMAT = "lmjx-trajectory/1"


def edges_in_region(bundle: Bundle, reach: ReachResult, region: tuple[float, float, float, float]) -> np.ndarray:
    """Ids (sorted, unique) of the edges during which the whole arm can act on an object in
    the axis-aligned rectangle `region` = (xmin, ymin, xmax, ymax) [m] of the table: those the
    map's spatial index lists for any reach cell whose square overlaps the rectangle."""
    try:
        xmin, ymin, xmax, ymax = (float(v) for v in region)
    except (TypeError, ValueError):
        raise ConfigError(f"a region is (xmin, ymin, xmax, ymax) in metres, got {region!r}") from None
    if not all(math.isfinite(v) for v in (xmin, ymin, xmax, ymax)) or xmin > xmax or ymin > ymax:
        raise ConfigError(f"a region is (xmin, ymin, xmax, ymax) with xmin <= xmax and ymin <= ymax, got {region!r}")
    half = reach.config.cell / 2
    ix = np.nonzero((reach.xs + half >= xmin) & (reach.xs - half <= xmax))[0]
    iy = np.nonzero((reach.ys + half >= ymin) & (reach.ys - half <= ymax))[0]
    nx = len(reach.xs)
    found = [bundle.edges_over(int(y), int(x), nx) for y in iy for x in ix]
    return np.unique(np.concatenate(found)).astype(np.int64) if found else np.zeros(0, np.int64)


@dataclass(frozen=True, eq=False)
class Edge:
    """One edge of a map (`MapFile.edge`): its states, dt apart, as the map stores them
    (float32 values, here as float64).  Arrays: q, qd (T, nq), t (T,), p (T, 3)."""

    index: int  # its id in the map
    q: np.ndarray = field(repr=False)  # (T, nq) joint angles [rad], locked joints at their angles
    qd: np.ndarray = field(repr=False)  # (T, nq) joint velocities [rad/s]
    t: np.ndarray = field(repr=False)  # (T,) time from the edge's start [s]
    p: np.ndarray = field(repr=False)  # (T, 3) the interaction point's position on its path [m], world frame
    point: str  # the interaction point that follows the twist ("hand", "wrist", "forearm", ...)
    joints: tuple[str, ...]  # the robot's joint names (its MJCF's), the columns of q and qd
    twist: tuple[float, ...]  # the commanded twist: linear [m/s] then angular [rad/s] velocity
    source: Any = field(default=None, repr=False)  # the MapFile it came from (for `lmjx.transit`)

    @property
    def dt(self) -> float:
        """The period of its states [s]."""
        return float(self.t[1] - self.t[0]) if len(self.t) > 1 else 0.0

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def __repr__(self) -> str:
        return (f"Edge({self.index}: {len(self.t)} states over {self.duration:.2f} s, point {self.point}, from "
                f"({self.p[0, 0]:.3f}, {self.p[0, 1]:.3f}, {self.p[0, 2]:.3f}) m)")  # fmt: skip


def read_edge(bundle: Bundle, index: int, joints: tuple[str, ...], sites: tuple[str, ...], source: Any) -> Edge:
    """Edge `index` of `bundle` (`joints`: the robot's joint names; `sites`: its site names)."""
    n = bundle.n_edges
    if isinstance(index, bool) or not isinstance(index, int | np.integer) or not 0 <= int(index) < n:
        raise ConfigError(f"edge {index!r} does not exist; the map has {n:,} edges (0 to {n - 1:,})")
    i = int(index)
    s = bundle.edge(i)
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
    )


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A time-stamped joint trajectory: positions q (N, nq) [rad] and velocities qd (N, nq)
    [rad/s] at times t (N,) [s] from its start, for the joints `joints` (in that order)."""

    t: np.ndarray = field(repr=False)
    q: np.ndarray = field(repr=False)
    qd: np.ndarray = field(repr=False)
    joints: tuple[str, ...]
    edge: int | None = None  # the map's edge it follows, if any
    point: str = ""  # that edge's interaction point

    def __repr__(self) -> str:
        return f"Trajectory({len(self.t)} points over {float(self.t[-1]):.3f} s, {len(self.joints)} joints)"

    def csv_text(self) -> str:
        """One row per point: time_from_start [s], then each joint's position [rad] (columns
        named by the joints), then each joint's velocity [rad/s] (`<joint>_velocity`); every
        value in the shortest form that reads back exactly."""
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["time_from_start", *self.joints, *(f"{j}_velocity" for j in self.joints)])
        for t, q, qd in zip(self.t, self.q, self.qd, strict=True):
            w.writerow([repr(float(t)), *(repr(float(v)) for v in q), *(repr(float(v)) for v in qd)])
        return buf.getvalue()

    def json_data(self) -> dict:
        """As a ROS trajectory_msgs/JointTrajectory: joint_names, and points each with
        positions, velocities and time_from_start (seconds, a float)."""
        return {
            "format": TRAJECTORY_FORMAT,
            "joint_names": list(self.joints),
            "points": [
                {"positions": [float(v) for v in q], "velocities": [float(v) for v in qd], "time_from_start": float(t)}
                for t, q, qd in zip(self.t, self.q, self.qd, strict=True)
            ],
            "edge": self.edge,
            "interaction_point": self.point,
        }

    def write(self, path: str | Path) -> Path:
        """Write it to `path` (atomically): CSV for a name ending in .csv, JSON for .json."""
        p = Path(path)
        if p.suffix.lower() not in (".csv", ".json"):
            raise ConfigError(f"{p}: a trajectory is written as .csv or .json; give a name ending in one of them")
        check_writable(p, "trajectory")
        text = self.csv_text() if p.suffix.lower() == ".csv" else json.dumps(self.json_data(), indent=1) + "\n"
        write_text_atomic(p, text)
        return p


def trajectory(edge: Edge, dt: float | None = None) -> Trajectory:
    """Edge `edge`'s joint trajectory sampled every `dt` seconds (default: its own period),
    from its start to its end (the last sample at the end even where `dt` does not divide
    the duration): positions interpolated linearly between the stored states, the motion
    Algorithm 2 integrated (q_{k+1} = q_k + qd_k dt); each point's velocity the one that
    carries the arm straight to the next point (the last: the last state's velocity).

    Its states are samples wherever `dt` divides the map's period; `Trajectory.write` exports
    it for a controller (CSV, or JSON as a ROS JointTrajectory)."""
    step = edge.dt if dt is None else dt
    if isinstance(step, bool) or not isinstance(step, int | float) or not (math.isfinite(step) and step > 0):
        raise ConfigError(f"dt must be a number of seconds above 0, got {dt!r}")
    end = edge.duration
    n = math.floor(end / step + 1e-9)
    times = np.arange(n + 1) * float(step)
    if end - times[-1] > 1e-9 * max(1.0, end):
        times = np.append(times, end)
    times[-1] = min(times[-1], end)
    if len(edge.t) < 2:
        return Trajectory(np.zeros(1), edge.q[:1].copy(), edge.qd[:1].copy(), edge.joints, edge.index, edge.point)
    period = edge.dt
    k = np.minimum(np.floor(times / period + 1e-9).astype(np.int64), len(edge.t) - 1)  # the interval each lies in
    into = np.clip(times - k * period, 0.0, None)[:, None]
    within = k < len(edge.t) - 1
    slope = np.diff(edge.q, axis=0) / period  # (T - 1, nq) each interval's velocity
    q = edge.q[k].copy()
    q[within] += slope[k[within]] * into[within]
    qd = np.concatenate([np.diff(q, axis=0) / np.diff(times)[:, None], edge.qd[-1:]])
    return Trajectory(times, q, qd, edge.joints, edge.index, edge.point)
