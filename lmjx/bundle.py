"""The failure-centric kinodynamic map (paper Algorithm 2): an edge bundle.

n Monte Carlo edges.  Per edge: a reachable cell of the Reach-Ability map, an interaction
point and a target in the cell are sampled; position-only IK (8 restarts) gives the start;
a constant twist (direction uniform in [-1, 1]^6, normalized; speed uniform in
`speed_range`) and a duration (uniform in `duration_range`) are sampled; the rollout kernel
follows the twist with the arm's dynamics, rejecting the edge at the first violated limit
or collision.  Valid edges are kept with every state (q, qd and the point's position), and a
spatial index lists, for each cell of the task plane, the edges whose point passes over it
low enough to touch an object there.  Everything random comes from the seed.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from .batching import ChunkedKernel, backend, device_description
from .errors import ConfigError
from .failure import Failure
from .ik_batch import IKBatch, default_ik_settings
from .kernels.rollout import REASONS, Limits, RolloutSettings, edge_rollout
from .progress import Progress
from .reach import NPM, ReachResult
from .robot import Robot, load_robot

IK_FAILED = "ik"  # an edge whose start could not be solved


@dataclass(frozen=True)
class BundleConfig:
    """Everything that defines an edge bundle (the reach map's own config is kept with it)."""

    edges: int | None = None  # sampled edges; default 10,000 on a CPU, 100,000 on a GPU
    dt: float = 0.02  # control period [s]
    duration_range: tuple[float, float] = (0.2, 2.0)  # [s]; 2.0 s = 100 steps of 0.02 s
    speed_range: tuple[float, float] = (0.1, 0.8)  # twist magnitude
    interaction_points: tuple[str, ...] = ("hand", "wrist", "forearm")
    ik_restarts: int = 8
    ik_iterations: int = 48
    damping: float = 1e-6  # of the damped least-squares inverse J^+
    index_height: float = 0.05  # the spatial index counts the point over a cell when the link's
    # lowest surface (point height minus its radius) is at most this high: it can touch an
    # object of this height there [m]
    index_substeps: int = 4  # points per step segment rasterized into the index
    seed: int = 0
    chunk: int | None = None  # edges per kernel call; default by platform

    def n_edges(self) -> int:
        return self.edges if self.edges is not None else (100_000 if backend() != "cpu" else 10_000)

    @property
    def steps(self) -> int:
        return round(self.duration_range[1] / self.dt)

    def validate(self, robot: Robot) -> None:
        if self.edges is not None and not 1 <= self.edges <= 50_000_000:
            raise ConfigError(f"--edges must be between 1 and 50,000,000, got {self.edges}")
        if not (math.isfinite(self.dt) and 0.001 <= self.dt <= 0.5):
            raise ConfigError(f"dt {self.dt:g} s is out of range (0.001 to 0.5)")
        lo, hi = self.duration_range
        if not (self.dt <= lo <= hi <= 20.0):
            raise ConfigError(f"duration range [{lo:g}, {hi:g}] s must satisfy dt <= min <= max <= 20")
        if not (0 < self.speed_range[0] <= self.speed_range[1]):
            raise ConfigError(f"speed range {self.speed_range} must be positive and ordered")
        for ip in self.interaction_points:
            if ip not in robot.interaction_points:
                known = ", ".join(sorted(robot.interaction_points))
                raise ConfigError(f"unknown interaction point '{ip}'; the model has: {known}")
        if not self.interaction_points:
            raise ConfigError("at least one interaction point is needed")
        if self.ik_restarts < 1 or self.ik_iterations < 1 or self.index_substeps < 1:
            raise ConfigError("ik_restarts, ik_iterations and index_substeps must be positive")
        if self.chunk is not None and self.chunk < 1:
            raise ConfigError(f"chunk must be positive, got {self.chunk}")

    def rollout_settings(self) -> RolloutSettings:
        return RolloutSettings(dt=self.dt, steps=self.steps, damping=self.damping, unroll_checks=backend() != "cpu")


@dataclass
class Bundle:
    """Valid edges, stored flat: edge e's states are rows offset[e] .. offset[e] + length[e] - 1."""

    config: BundleConfig
    failure: Failure
    offset: np.ndarray  # (E,) int64
    length: np.ndarray  # (E,) int32, states per edge (control steps + 1)
    q: np.ndarray  # (S, 7) float32 joint angles (locked joints at their angles)
    qd: np.ndarray  # (S, 7) float32 joint velocities
    p: np.ndarray  # (S, 3) float32 world position of the interaction point
    twist: np.ndarray  # (E, 6) float32 commanded linear [m/s] and angular [rad/s] velocity
    duration: np.ndarray  # (E,) float32 [s]
    site: np.ndarray  # (E,) int16 model site index of the interaction point
    start_cell: np.ndarray  # (E, 2) int32 (iy, ix) of the reach cell the edge starts in
    min_manipulability: np.ndarray  # (E,) float32
    peak_torque_ratio: np.ndarray  # (E,) float32, max |tau| / tau_max over free joints and states
    peak_velocity_ratio: np.ndarray  # (E,) float32
    peak_acceleration_ratio: np.ndarray  # (E,) float32
    index_offset: np.ndarray  # (ny * nx + 1,) int64 CSR offsets over reach cells (iy * nx + ix)
    index_edges: np.ndarray  # (K,) int32 edge ids
    sampled: int
    rejected: dict[str, int]  # reason -> count (includes 'ik')
    seconds: float  # wall time, compilation excluded
    compile_seconds: float
    rollout_seconds: float  # of which: the rollout kernels
    edge_steps: int  # nominal work: edges rolled out x the longest edge's steps
    states_evaluated: int  # states actually evaluated (each edge up to its end or first violation)
    device: str

    @property
    def n_edges(self) -> int:
        return len(self.offset)

    def edge(self, e: int) -> dict[str, np.ndarray]:
        """The states of edge e."""
        sl = slice(int(self.offset[e]), int(self.offset[e] + self.length[e]))
        return {"q": self.q[sl], "qd": self.qd[sl], "p": self.p[sl]}

    def edges_over(self, iy: int, ix: int, nx: int) -> np.ndarray:
        """Ids of the edges whose point passes over reach cell (iy, ix) low enough to push there."""
        c = iy * nx + ix
        return self.index_edges[self.index_offset[c] : self.index_offset[c + 1]]

    def summary(self) -> dict:
        return {
            "edges_sampled": self.sampled,
            "edges_valid": self.n_edges,
            "rejected": dict(self.rejected),
            "states": len(self.q),
            "edge_steps": self.edge_steps,
            "states_evaluated": self.states_evaluated,
            "seconds": round(self.seconds, 4),
            "rollout_seconds": round(self.rollout_seconds, 4),
            "compile_seconds": round(self.compile_seconds, 4),
            "edge_steps_per_s": round(self.edge_steps / max(self.rollout_seconds, 1e-9), 1),
            "device": self.device,
        }


def _rollout_kernel(robot: Robot, failure: Failure, sites: tuple[int, ...], settings: RolloutSettings, chunk: int):
    free = failure.free(robot.nq)
    q_fixed = failure.q_fixed(robot.nq)
    limits = Limits(robot.qd_max, robot.qdd_max, robot.tau_max, robot.friction)

    def one(site, q0, twist, length):
        return edge_rollout(robot.arm, robot.inertials, limits, settings, free, q_fixed, sites, site, q0, twist, length)

    inputs = [(np.int32, ()), (np.float32, (len(free),)), (np.float32, (6,)), (np.int32, ())]
    key = ("rollout", robot.model_hash, free, tuple(q_fixed), sites, settings)
    return ChunkedKernel(key, one, [], inputs, chunk)


@dataclass
class EdgeSamples:
    """Sampled edges and their solved starts (the inputs of the rollouts)."""

    sites: tuple[int, ...]  # model site of each interaction point; `which` indexes it
    start: np.ndarray  # (n, 2) reach cell (iy, ix)
    which: np.ndarray  # (n,) int32
    twist: np.ndarray  # (n, 6) float32
    length: np.ndarray  # (n,) int32 control steps
    has_start: np.ndarray  # (n,) bool: the start IK succeeded
    q_start: np.ndarray  # (n, nf) float32 start of the free joints (meaningful where has_start)
    compile_seconds: float
    chunk: int


def sample_edges(
    reach: ReachResult, config: BundleConfig, robot: Robot, progress: Progress | None = None
) -> EdgeSamples:
    """Sample n edges (cell, point, target, twist, duration) and solve their starts."""
    failure = reach.failure
    n = config.n_edges()
    rng = np.random.default_rng(config.seed)
    free = failure.free(robot.nq)
    nf = len(free)
    cells = np.argwhere(reach.labels >= NPM)  # (nc, 2) iy, ix with a solution
    if len(cells) == 0:
        raise ConfigError(f"failure {failure.spec}: no reachable cell on the task plane, so no edge can start")
    sites = tuple(robot.interaction_points[name] for name in config.interaction_points)
    radius = robot.arm.site_radius[list(sites)]
    rc = reach.config

    start = cells[rng.integers(0, len(cells), n)]
    which = rng.integers(0, len(sites), n).astype(np.int32)
    xy = np.stack([reach.xs[start[:, 1]], reach.ys[start[:, 0]]], axis=1) + rng.uniform(-0.5, 0.5, (n, 2)) * rc.cell
    z_lo = radius[which]
    z_hi = np.maximum(radius[which], rc.object_height + radius[which] - rc.npm_overlap)
    targets = np.concatenate([xy, z_lo[:, None], z_hi[:, None]], axis=1)
    lo, hi = robot.lower[list(free)], robot.upper[list(free)]
    m = config.ik_restarts
    q0 = (lo + rng.random((n, m, nf)) * (hi - lo)).astype(np.float32)
    direction = rng.uniform(-1.0, 1.0, (n, 6))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    speed = rng.uniform(*config.speed_range, n)
    twist = (direction * speed[:, None]).astype(np.float32)
    duration = rng.uniform(*config.duration_range, n)
    length = np.clip(np.round(duration / config.dt), 1, config.steps).astype(np.int32)

    chunk = config.chunk or (1 << 17 if backend() != "cpu" else 512)
    # Starts: position-only IK for the sampled point, M restarts each.
    ik = IKBatch(
        robot,
        failure,
        sites,
        default_ik_settings(iterations=config.ik_iterations, cube_half=rc.object_height / 2),
        min(chunk * m, -(-n * m // 1024) * 1024),
    )
    res = ik.solve(
        np.repeat(targets, m, axis=0),
        np.repeat(which, m),
        np.zeros(n * m, bool),
        q0.reshape(n * m, nf),
        progress=progress.update if progress else None,
    )
    ok = res["ok"].reshape(n, m)
    first = np.argmax(ok, axis=1)
    q_start = res["q"].reshape(n, m, -1)[np.arange(n), first][:, list(free)].astype(np.float32)
    return EdgeSamples(sites, start, which, twist, length, ok.any(axis=1), q_start, ik.compile_seconds, chunk)


def roll_out(
    robot: Robot, failure: Failure, samples: EdgeSamples, config: BundleConfig, progress: Progress | None = None
) -> tuple[np.ndarray, dict[str, np.ndarray], ChunkedKernel]:
    """Roll out the sampled edges that have a start; returns their indices (sampling order),
    the kernel's per-edge results in that order, and the kernel (for its timings)."""
    idx = np.nonzero(samples.has_start)[0]
    # Longest first, so that each chunk's loop stops with edges of about its own length.
    idx = idx[np.argsort(-samples.length[idx], kind="stable")]
    roll_chunk = min(samples.chunk, max(1024, -(-len(idx) // 1024) * 1024))
    kernel = _rollout_kernel(robot, failure, samples.sites, config.rollout_settings(), roll_chunk)
    out = kernel.run(
        samples.which[idx],
        samples.q_start[idx],
        samples.twist[idx],
        samples.length[idx],
        progress=progress.update if progress else None,
    )
    back = np.argsort(idx, kind="stable")  # to sampling order
    return idx[back], {k: v[back] for k, v in out.items()}, kernel


def build_bundle(
    reach: ReachResult, config: BundleConfig | None = None, robot: Robot | None = None, progress: bool = False
) -> Bundle:
    """Sample, solve and roll out the edges of `reach`'s failure."""
    robot = robot or load_robot()
    config = config or BundleConfig()
    config.validate(robot)
    failure = reach.failure
    device = device_description()
    t_start = time.perf_counter()
    n = config.n_edges()
    free = failure.free(robot.nq)
    bar = Progress(
        total=n * (config.ik_restarts + 1), desc=f"edges {failure.spec}: start IK", enabled=progress, unit="item"
    )
    samples = sample_edges(reach, config, robot, bar)
    bar.set_description(f"edges {failure.spec}: rollouts")
    idx, out, kernel = roll_out(robot, failure, samples, config, bar)
    bar.update(n - len(idx))
    bar.close()
    sites, start, which, twist, length = samples.sites, samples.start, samples.which, samples.twist, samples.length
    radius = robot.arm.site_radius[list(sites)]

    valid_local = out["valid"].astype(bool)
    keep = idx[valid_local]
    rejected = {IK_FAILED: int(n - len(idx))}
    for code, name in enumerate(REASONS[1:], start=1):
        rejected[name] = int(np.sum(out["reason"][~valid_local] == code))

    lens = length[keep] + 1  # states per edge
    offset = np.zeros(len(keep), np.int64)
    if len(keep):
        offset[1:] = np.cumsum(lens)[:-1]
    rows = np.concatenate([np.arange(k) for k in lens]) if len(keep) else np.zeros(0, np.int64)
    e_of_row = np.repeat(np.arange(len(keep)), lens)
    src = np.nonzero(valid_local)[0][e_of_row]
    q_fixed = failure.q_fixed(robot.nq).astype(np.float32)
    q_full = np.broadcast_to(q_fixed, (len(rows), robot.nq)).copy()
    qd_full = np.zeros((len(rows), robot.nq), np.float32)
    q_full[:, list(free)] = out["q"][src, rows]
    qd_full[:, list(free)] = out["qd"][src, rows]
    p = out["p"][src, rows].astype(np.float32)

    index_offset, index_edges = spatial_index(
        reach, p, e_of_row, offset, lens, radius[which[keep]], config.index_height, config.index_substeps
    )
    return Bundle(
        config=config,
        failure=failure,
        offset=offset,
        length=lens.astype(np.int32),
        q=q_full,
        qd=qd_full,
        p=p,
        twist=twist[keep],
        duration=(length[keep] * config.dt).astype(np.float32),
        site=np.array(sites, np.int16)[which[keep]],
        start_cell=start[keep].astype(np.int32),
        min_manipulability=out["min_manipulability"][valid_local].astype(np.float32),
        peak_torque_ratio=out["peak_torque_ratio"][valid_local].astype(np.float32),
        peak_velocity_ratio=out["peak_velocity_ratio"][valid_local].astype(np.float32),
        peak_acceleration_ratio=out["peak_acceleration_ratio"][valid_local].astype(np.float32),
        index_offset=index_offset,
        index_edges=index_edges,
        sampled=n,
        rejected=rejected,
        seconds=time.perf_counter() - t_start - samples.compile_seconds - kernel.compile_seconds,
        compile_seconds=samples.compile_seconds + kernel.compile_seconds,
        rollout_seconds=kernel.kernel_seconds,
        edge_steps=len(idx) * config.steps,
        states_evaluated=int(np.sum(np.where(out["valid"], length[idx], out["fail_step"]) + 1)),
        device=device,
    )


def spatial_index(
    reach: ReachResult,
    p: np.ndarray,
    edge_of_row: np.ndarray,
    offset: np.ndarray,
    length: np.ndarray,
    edge_radius: np.ndarray,
    height: float,
    substeps: int,
) -> tuple[np.ndarray, np.ndarray]:
    """CSR lists, per reach cell, of the edges whose point passes over the cell with the
    link's lowest surface at most `height` above the table.  Each step segment is sampled at
    `substeps` points, so a point moving up to a cell per step is not missed."""
    ny, nx = reach.labels.shape
    cell = reach.config.cell
    x0 = reach.xs[0] - cell / 2
    y0 = reach.ys[0] - cell / 2
    pts, owners = [p], [edge_of_row]
    if len(p):
        last = np.zeros(len(p), bool)
        last[offset + length - 1] = True
        a = np.nonzero(~last)[0]
        for s in range(1, substeps):
            t = s / substeps
            pts.append(p[a] * (1 - t) + p[a + 1] * t)
            owners.append(edge_of_row[a])
    pts_all = np.concatenate(pts)
    own = np.concatenate(owners)
    low = pts_all[:, 2] - edge_radius[own] <= height
    ix = np.floor((pts_all[:, 0] - x0) / cell).astype(np.int64)
    iy = np.floor((pts_all[:, 1] - y0) / cell).astype(np.int64)
    inside = low & (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    pairs = np.unique((iy[inside] * nx + ix[inside]) * max(1, len(offset)) + own[inside])
    cells = pairs // max(1, len(offset))
    edges = (pairs % max(1, len(offset))).astype(np.int32)
    counts = np.bincount(cells, minlength=ny * nx)
    index_offset = np.zeros(ny * nx + 1, np.int64)
    index_offset[1:] = np.cumsum(counts)
    return index_offset, edges
