"""The map's edges turned about the arm's base joint: more edges over a target than the map holds.

Where the first joint of the arm is a free hinge whose axis is vertical in the world (Panda's
J1), turning a whole edge about that axis by an angle delta gives another valid edge: the
dynamics (mass matrix, Coriolis, gravity, friction) do not depend on that joint's angle, so
every joint velocity, acceleration and torque is the edge's own; the moving links keep their
relative poses (no new self-collision); the table's top is a plane under the arm.  What can
differ: the joint's limits (checked over the edge's states) and the links that do not turn
(the base; the table's edges), which the planner's transit checks test on the states a
turned edge executes (`lmjx.planner.transit.TransitPlanner.edge_prefixes`).

A map of few edges leaves few of them over any one target that start clear of it and of its
neighbours and then act on it (the spatial index counts every edge over its own start cell:
most edges over a target start where the target stands).  `turned_over_target` offers, for a
target at polar angle phi about the axis, the map's edges whose indexed cells lie at the
target's distance from the axis, turned by phi less their cell's angle (binned at TURN_STEP,
at most TURNS_PER_EDGE angles per edge, spread over its range), less those whose turned start
puts the interaction point within START_CLEAR of the target.  `TurnedEdges` is a view over
the bundle that the transit planner takes in its place (`q_start`, `edge`, `prefetch`).

Both lmjx's planner (`lmjx.planner.edge_planner`) and the public API (`MapFile.edges_over`,
`MapFile.edge`) offer turned edges from here, so that a planner of one's own is offered
the planner's copies.  Nothing here plans: it reads a bundle and turns its states.
"""

from __future__ import annotations

import math
import weakref
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import mujoco
import numpy as np

from lmjx.mapfile.bundle import Bundle, EdgeStates
from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.reach.reachability import ReachResult
from lmjx.runtime.cores import usable_cores

TURN_STEP_DEG = 1  # turns are whole degrees (a record's `turn_deg` gives the turn exactly)
TURNS_PER_EDGE = 4  # turned copies of one edge offered per target at most
# a turned start whose interaction point lies this near the target's centre starts inside its
# margin (the 5 cm cube's half diagonal plus the margins): not offered (a quarter of the
# turned copies; none of them usable where measured)
START_CLEAR = 0.08  # [m]
VERTICAL = 1e-9  # the axis counts as vertical when its z component is within this of +-1
PARTS = 8  # `turned_over_target`'s work in this many parts on threads of its own


@dataclass(frozen=True)
class TurnAxis:
    """The base joint: its index in q, the sign of its axis (+1 up, -1 down) and where the
    axis meets the table's plane (x, y)."""

    joint: int
    sign: float
    anchor: np.ndarray


def turn_axis(robot: Robot, failure: Failure) -> TurnAxis | None:
    """The arm's base joint, when turning about it turns the whole arm as a rigid body: a free
    hinge with no joint between it and the world, every other joint below it, and its axis
    vertical in the world; None otherwise (no turned edges are offered)."""
    m = robot.mj
    if m.njnt == 0:
        return None
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    moving = set(int(m.jnt_bodyid[j]) for j in range(robot.nq))
    for j in range(robot.nq):
        if m.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE or j not in failure.free(robot.nq):
            continue
        body = int(m.jnt_bodyid[j])
        above, b = [], int(m.body_parentid[body])
        while b != 0:
            above.append(b)
            b = int(m.body_parentid[b])
        if any(a in moving for a in above):
            continue  # a joint above it: not the base joint
        if any(int(m.jnt_bodyid[k]) == body for k in range(robot.nq) if k != j):
            continue  # another joint on the same body
        if not all(_below(m, int(m.jnt_bodyid[k]), body) for k in range(robot.nq)):
            continue  # a joint outside its subtree
        axis = np.asarray(d.xaxis[j], np.float64)
        if abs(abs(axis[2]) - 1.0) > VERTICAL:
            return None
        return TurnAxis(j, float(np.sign(axis[2])), np.asarray(d.xanchor[j][:2], np.float64).copy())
    return None


def _below(m: mujoco.MjModel, body: int, root: int) -> bool:
    while body not in (root, 0):
        body = int(m.body_parentid[body])
    return body == root


def turn_xy(xy: np.ndarray, angle: np.ndarray | float, anchor: np.ndarray) -> np.ndarray:
    """Points (..., 2) turned by `angle` (world radians, counter-clockwise seen from above) about `anchor`."""
    c, s = np.cos(angle), np.sin(angle)
    x, y = xy[..., 0] - anchor[0], xy[..., 1] - anchor[1]
    return np.stack([c * x - s * y + anchor[0], s * x + c * y + anchor[1]], axis=-1)


class TurnedEdges:
    """A view over `base` holding edges `ids` turned by `delta` (radians of the base joint; 0:
    the edge as the map holds it): edge i of the view is base edge ids[i] with the base joint
    `axis.joint` at delta[i] more in every state, its interaction point turned with it.  The
    transit planner takes it in the bundle's place (candidates are 0 .. len(ids) - 1)."""

    def __init__(self, base: Bundle, ids: np.ndarray, delta: np.ndarray, axis: TurnAxis) -> None:
        self.base = base
        self.ids = np.asarray(ids, np.int64)
        self.delta = np.asarray(delta, np.float64)
        self.axis = axis
        q = np.array(base.q_start[self.ids], copy=True)
        q[:, axis.joint] += self.delta.astype(q.dtype)
        self.q_start = q
        self.site = base.site[self.ids]

    @property
    def n_edges(self) -> int:
        return len(self.ids)

    def source(self, i: int) -> tuple[int, float]:
        """The map's edge that view edge i is, and its turn [rad]."""
        return int(self.ids[i]), float(self.delta[i])

    def edge(self, i: int, names: tuple[str, ...] = ("q", "qd", "p")) -> dict[str, np.ndarray]:
        """The states of view edge i (those of its map edge, turned)."""
        out = self.base.edge(int(self.ids[i]), names)
        d = self.delta[i]
        if d == 0.0:
            return out
        if "q" in out:
            q = np.array(out["q"], copy=True)
            q[:, self.axis.joint] += np.asarray(d, q.dtype)
            out["q"] = q
        if "p" in out:
            p = np.array(out["p"], copy=True)
            p[:, :2] = turn_xy(p[:, :2].astype(np.float64), self.axis.sign * d, self.axis.anchor)
            out["p"] = p
        return out

    def states(self, edges: np.ndarray, names: tuple[str, ...] = ("q", "qd", "p")) -> EdgeStates:
        """`Bundle.states` of view edges `edges`: their map edges' states read at once, turned."""
        edges = np.asarray(edges, np.int64)
        out, lengths = self.base.states(self.ids[edges], names)
        d = np.repeat(self.delta[edges], lengths)
        if "q" in out:
            q = out["q"]
            q[:, self.axis.joint] += d.astype(q.dtype)
        if "p" in out and d.any():
            p = out["p"]
            turned = d != 0.0
            p[turned, :2] = turn_xy(p[turned, :2].astype(np.float64), self.axis.sign * d[turned], self.axis.anchor)
        return out, lengths

    def prefetch(self, edges: np.ndarray, names: tuple[str, ...] = ("q", "qd", "p")) -> None:
        self.base.prefetch(np.unique(self.ids[np.asarray(edges, np.int64)]), names)


@dataclass(frozen=True)
class _Pool:
    """What `turned_over_target` needs of a bundle, computed once per bundle."""

    axis: TurnAxis
    # the index's entries sorted by band (their cell's distance from the axis in steps of
    # `band_width`: a ring about the axis is one slice), then edge, then angle, decreasing
    # (an edge's turns then come out nearly sorted: `turned_over_target`)
    band: np.ndarray  # (K,) int64
    band_width: float
    radius: np.ndarray  # (K,) each index entry's cell: distance from the axis
    angle: np.ndarray  # (K,) ... and polar angle about it [rad]
    edges: np.ndarray  # (K,) each index entry's edge
    low: np.ndarray  # (E,) each edge's lowest base-joint angle over its states
    high: np.ndarray  # (E,) ... highest
    start_xy: np.ndarray  # (E, 2) each edge's interaction point at its start
    lower: float  # the base joint's limits
    upper: float


_POOLS: dict[int, tuple[weakref.ref, _Pool | None]] = {}


def _pool(bundle: Bundle, reach: ReachResult, robot: Robot, failure: Failure) -> _Pool | None:
    held = _POOLS.get(id(bundle))
    if held is not None and held[0]() is bundle:
        return held[1]
    axis = turn_axis(robot, failure)
    pool = None
    if axis is not None:
        nx = len(reach.xs)
        cells = np.repeat(np.arange(len(bundle.index_offset) - 1), np.diff(bundle.index_offset))
        cx = reach.xs[cells % nx] - axis.anchor[0]
        cy = reach.ys[cells // nx] - axis.anchor[1]
        column = _column(bundle.q, axis.joint)
        starts = np.asarray(bundle.offset, np.int64)
        radius, angle = np.hypot(cx, cy), np.arctan2(cy, cx)
        width = reach.config.cell / 2
        band = np.floor(radius / width).astype(np.int64)
        edges = np.asarray(bundle.index_edges, np.int64)
        order = np.lexsort((-angle, edges, band))
        pool = _Pool(
            axis=axis,
            band=band[order],
            band_width=width,
            radius=radius[order],
            angle=angle[order],
            edges=edges[order],
            low=np.minimum.reduceat(column, starts) if len(starts) else np.zeros(0),
            high=np.maximum.reduceat(column, starts) if len(starts) else np.zeros(0),
            start_xy=_rows(bundle.p, starts)[:, :2],
            lower=float(robot.lower[axis.joint]),
            upper=float(robot.upper[axis.joint]),
        )
    key = id(bundle)
    _POOLS[key] = (weakref.ref(bundle, lambda _: _POOLS.pop(key, None)), pool)
    return pool


def _column(data, j: int, block: int = 1 << 20) -> np.ndarray:
    """One column of the states (an array, or a lazily read dataset: in blocks of rows)."""
    if isinstance(data, np.ndarray):
        return np.asarray(data[:, j], np.float64)
    n = len(data)
    return np.concatenate([np.asarray(data[a : min(a + block, n)])[:, j] for a in range(0, n, block)] or [[]]).astype(
        np.float64
    )


def _rows(data, rows: np.ndarray) -> np.ndarray:
    """Rows of the states (an array, or a lazily read dataset)."""
    if isinstance(data, np.ndarray):
        return np.asarray(data[rows], np.float64).reshape(len(rows), -1)
    n, block = len(data), 1 << 20
    out = np.zeros((len(rows), np.asarray(data[:1]).shape[1]))
    for a in range(0, n, block):
        k = (rows >= a) & (rows < a + block)
        if k.any():
            out[k] = np.asarray(data[a : min(a + block, n)])[rows[k] - a]
    return out


def turned_over_target(
    bundle: Bundle,
    reach: ReachResult,
    robot: Robot,
    failure: Failure,
    target_xy: np.ndarray,
    half: float,
    margin: float,
    per_edge: int = TURNS_PER_EDGE,
) -> tuple[np.ndarray, np.ndarray]:
    """Turned copies of the map's edges whose point passes over the target: (edge ids, turns
    [rad of the base joint]), sorted by edge then turn, no turn 0 among them; empty where the
    arm has no base joint to turn about (`turn_axis`).  An index entry whose cell lies within
    half + margin + half a cell of the target's distance from the axis gives its edge turned by
    the target's polar angle less the cell's, in whole TURN_STEP_DEG; a turn that takes the
    base joint past its limits anywhere along the edge, or the turned start's interaction point
    within START_CLEAR of the target, is left out."""
    pool = _pool(bundle, reach, robot, failure)
    empty = np.zeros(0, np.int64), np.zeros(0)
    if pool is None or not len(pool.edges):
        return empty
    ax = pool.axis
    target_xy = np.asarray(target_xy, np.float64)
    t = target_xy - ax.anchor
    r_t, phi_t = float(np.hypot(*t)), float(np.arctan2(t[1], t[0]))
    ring = half + margin + reach.config.cell / 2
    # the entries whose cell lies within `ring` of the target's distance from the axis: in the
    # slice of their bands
    bands = np.floor(np.array([r_t - ring, r_t + ring]) / pool.band_width).astype(np.int64)
    lo = int(np.searchsorted(pool.band, bands[0] - 1, "left"))
    hi = int(np.searchsorted(pool.band, bands[1] + 1, "right"))
    span = 2 * (360 // TURN_STEP_DEG) + 1
    narrow = len(pool.low) * span < 2**32  # (keys of 32 bits where they fit)

    def keys_of(a: int, b: int) -> np.ndarray:  # the sorted (edge, turn) keys of entries a..b-1 of the pool
        near = slice(a, b)
        keep_near = np.abs(pool.radius[near] - r_t) <= ring  # (the ring's own test)
        e = pool.edges[near][keep_near]
        world = (phi_t - pool.angle[near][keep_near] + math.pi) % (2 * math.pi) - math.pi  # the turn seen from above
        steps = np.round(np.degrees(ax.sign * world) / TURN_STEP_DEG).astype(np.int64)  # in the joint's sense
        keys = e * span + steps + span // 2
        # (a band's keys are sorted but for an edge's turns that wrap past 180 degrees: few runs)
        return np.sort(keys.astype(np.uint32) if narrow else keys, kind="stable")

    # unique (edge, turn) pairs, sorted by edge then turn (np.unique hashes first: 10x slower here)
    pairs = np.sort(np.concatenate(_in_parts(keys_of, lo, hi)), kind="stable")  # (sorted parts: merged)
    pairs = pairs[np.r_[True, pairs[1:] != pairs[:-1]]].astype(np.int64)
    if not len(pairs):
        return empty
    # each edge's pairs (whole edges per part): those kept, with their turns
    edge_of = pairs // span
    cuts = [int(np.searchsorted(edge_of, edge_of[min(len(pairs) - 1, k * len(pairs) // PARTS)]))
            for k in range(1, PARTS)]  # fmt: skip
    bounds = [0, *cuts, len(pairs)]

    def kept(a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        pe, ps = edge_of[a:b], pairs[a:b] % span - span // 2
        # no turn 0, and none past the base joint's limits anywhere along the edge
        turn = np.radians(ps * TURN_STEP_DEG)
        ok = (ps != 0) & (pool.low[pe] + turn >= pool.lower) & (pool.high[pe] + turn <= pool.upper)
        pe, ps = pe[ok], ps[ok]
        if not len(pe):
            return pe, np.zeros(0)
        # at most per_edge turns per edge, spread evenly over its turns: of an edge's n turns,
        # the ranks round(k (n - 1) / (per_edge - 1)), k = 0 .. per_edge - 1 (in integers: exactly)
        first = np.flatnonzero(np.r_[True, pe[1:] != pe[:-1]])
        count = np.diff(np.r_[first, len(pe)])
        rank = np.arange(len(pe)) - np.repeat(first, count)
        n = np.repeat(count, count)
        keep = n <= per_edge
        d = max(per_edge - 1, 1)
        for k in range(per_edge):
            keep |= rank == (2 * k * (n - 1) + d) // (2 * d)
        pe, ps = pe[keep], ps[keep]
        turn = np.radians(ps * TURN_STEP_DEG)
        start = turn_xy(pool.start_xy[pe], ax.sign * turn, ax.anchor)
        clear = np.hypot(*(start - target_xy).T) >= START_CLEAR
        return pe[clear], turn[clear]

    parts = _pooled().map(lambda k: kept(bounds[k], bounds[k + 1]), range(len(bounds) - 1))
    ids, turns = zip(*parts, strict=True)
    return np.concatenate(ids), np.concatenate(turns)


def _in_parts(fn, a: int, b: int) -> list:
    """fn over PARTS contiguous parts of a..b-1, on the pool's threads (numpy lets go of the
    interpreter lock over large arrays), in order."""
    bounds = np.linspace(a, b, PARTS + 1).astype(np.int64)
    return list(_pooled().map(lambda k: fn(int(bounds[k]), int(bounds[k + 1])), range(PARTS)))


_THREADS: list[ThreadPoolExecutor] = []


def _pooled() -> ThreadPoolExecutor:
    if not _THREADS:
        _THREADS.append(ThreadPoolExecutor(min(PARTS, usable_cores()), thread_name_prefix="lmjx-turned"))
    return _THREADS[0]
