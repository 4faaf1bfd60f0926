"""The failure-centric kinodynamic map (paper Algorithm 2): an edge bundle.

n Monte Carlo edges.  Per edge: a reachable cell of the Reach-Ability map, an interaction
point and a target in the cell are sampled; position-only IK (8 restarts) gives the start;
a constant twist (direction uniform in [-1, 1]^6, normalized; speed uniform in
`speed_range`) and a duration (uniform in `duration_range`) are sampled; the rollout kernel
follows the twist with the arm's dynamics, rejecting the edge at the first violated limit
or collision.  Valid edges are kept with every state (q, qd and the point's position), and a
spatial index lists, for each cell of the task plane, the edges whose point passes over it
low enough to touch an object there.

Randomness is counter-based: edge i's draws are row i of a Philox stream keyed by the seed
(`edge_uniforms`), so an edge is the same whatever range of edges it is computed with.
Edges are processed in chunks (`EdgeChunk`: the valid edges of sampled edges [start, stop),
packed, with their spatial-index entries); `build_bundle` packs every chunk in memory,
`lmjx.edgestream` streams chunks to a map file in bounded memory.  Either way the same seed
gives the same edges, for any chunk size and any number of devices.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .batching import ChunkedKernel, backend, device_description
from .errors import ConfigError
from .failure import Failure
from .ik_batch import IKBatch, default_chunk, default_ik_settings
from .kernels.rollout import REASONS, Limits, RolloutSettings, edge_rollout
from .progress import Progress
from .reach import NPM, ReachResult
from .reprs import config_repr
from .robot import Robot, load_robot

IK_FAILED = "ik"  # an edge whose start could not be solved
MAX_EDGES = 50_000_000


@dataclass(frozen=True)
class BundleConfig:
    """Everything that defines an edge bundle (the reach map's own config is kept with it),
    and how it is computed (`chunk`, `build_chunk`: not part of the result)."""

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
    chunk: int | None = None  # edges per kernel launch (per device); default by platform
    build_chunk: int | None = None  # edges sampled, rolled out and packed at a time; default by platform

    __repr__ = config_repr

    def n_edges(self) -> int:
        return self.edges if self.edges is not None else (100_000 if backend() != "cpu" else 10_000)

    @property
    def steps(self) -> int:
        return round(self.duration_range[1] / self.dt)

    def kernel_chunk(self) -> int:
        return self.chunk or (1 << 17 if backend() != "cpu" else 512)

    def edges_per_chunk(self, devices: int = 1) -> int:
        """Edges per streamed chunk: bounded host memory (the rollouts of a chunk come back
        whole: about 7 kB per edge) and whole launches on every device."""
        if self.build_chunk:
            return self.build_chunk
        return self.kernel_chunk() * devices * (2 if backend() != "cpu" else 32)

    def edges_per_job(self) -> int:
        """Edges per streamed chunk when each device takes whole chunks, two at a time
        (`lmjx.edgestream`): one launch on a GPU, 32 on a CPU."""
        if self.build_chunk:
            return self.build_chunk
        return self.kernel_chunk() * (1 if backend() != "cpu" else 32)

    def validate(self, robot: Robot) -> None:
        if self.edges is not None and not 1 <= self.edges <= MAX_EDGES:
            raise ConfigError(f"--edges must be between 1 and {MAX_EDGES:,}, got {self.edges}")
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
        if self.build_chunk is not None and self.build_chunk < 1:
            raise ConfigError(f"--chunk must be positive, got {self.build_chunk}")

    def rollout_settings(self) -> RolloutSettings:
        return RolloutSettings(dt=self.dt, steps=self.steps, damping=self.damping, unroll_checks=backend() != "cpu")

    def content(self) -> dict:
        """The fields that define the edges (a resumed build must match them)."""
        skip = {"chunk", "build_chunk"}
        return {k: v for k, v in self.__dict__.items() if k not in skip}


@dataclass
class Bundle:
    """Valid edges, stored flat: edge e's states are rows offset[e] .. offset[e] + length[e] - 1.

    q, qd and p are arrays, or, for a map opened lazily (`mapfile.load_map(lazy=True)`),
    HDF5 datasets read on demand; everything else is in memory.
    """

    config: BundleConfig
    failure: Failure
    offset: np.ndarray  # (E,) int64
    length: np.ndarray  # (E,) int32, states per edge (control steps + 1)
    q: Any  # (S, nq) float32 joint angles (locked joints at their angles)
    qd: Any  # (S, nq) float32 joint velocities
    p: Any  # (S, 3) float32 world position of the interaction point
    q_start: np.ndarray  # (E, nq) float32 each edge's first state (where its transit goes)
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

    def __repr__(self) -> str:
        return (
            f"Bundle({self.failure.spec!r}: {self.n_edges:,} edges of {self.sampled:,} sampled, "
            f"{int(self.length.sum()):,} states, dt {self.config.dt:g} s, seed {self.config.seed})"
        )

    @property
    def n_states(self) -> int:
        return len(self.q)

    def edge(self, e: int, names: tuple[str, ...] = ("q", "qd", "p")) -> dict[str, np.ndarray]:
        """The states of edge e (the fields `names` of q, qd, p)."""
        sl = slice(int(self.offset[e]), int(self.offset[e] + self.length[e]))
        return {name: np.asarray(getattr(self, name)[sl]) for name in names}

    def prefetch(self, edges: np.ndarray, names: tuple[str, ...] = ("q", "qd", "p")) -> None:
        """Read the states of many edges at once from a lazily opened map (a no-op when the
        states are in memory): `edge` then finds them decompressed."""
        edges = np.asarray(edges, np.int64)
        ranges = list(zip(self.offset[edges], self.offset[edges] + self.length[edges], strict=True))
        for name in names:
            data = getattr(self, name)
            if hasattr(data, "prefetch"):
                data.prefetch(ranges)

    def edges_over(self, iy: int, ix: int, nx: int) -> np.ndarray:
        """Ids of the edges whose point passes over reach cell (iy, ix) low enough to push there."""
        c = iy * nx + ix
        return self.index_edges[self.index_offset[c] : self.index_offset[c + 1]]

    def summary(self) -> dict:
        return {
            "edges_sampled": self.sampled,
            "edges_valid": self.n_edges,
            "rejected": dict(self.rejected),
            "states": self.n_states,
            "edge_steps": self.edge_steps,
            "states_evaluated": self.states_evaluated,
            "seconds": round(self.seconds, 4),
            "rollout_seconds": round(self.rollout_seconds, 4),
            "compile_seconds": round(self.compile_seconds, 4),
            "edge_steps_per_s": round(self.edge_steps / max(self.rollout_seconds, 1e-9), 1),
            "device": self.device,
        }


# ------------------------------------------------------------------------------- sampling


def random_width(robot: Robot, config: BundleConfig) -> int:
    """Uniforms drawn per edge (a multiple of 4: Philox makes four 64-bit words a step): cell,
    point, target (2), restarts (M x nq), twist direction (6), speed, duration."""
    return -(-(12 + config.ik_restarts * robot.nq) // 4) * 4


def edge_uniforms(seed: int, start: int, stop: int, width: int) -> np.ndarray:
    """(stop - start, width) uniforms in [0, 1): row i belongs to edge start + i and is the
    same whatever range it is drawn in (Philox is counter-based: skip to the range's start)."""
    bits = np.random.Philox(key=seed)
    bits.advance(start * width // 4)
    return np.random.Generator(bits).random((stop - start, width))


@dataclass
class EdgeSamples:
    """Sampled edges [start, stop) and their solved starts (the inputs of the rollouts)."""

    start: int
    sites: tuple[int, ...]  # model site of each interaction point; `which` indexes it
    cell: np.ndarray  # (n, 2) reach cell (iy, ix)
    which: np.ndarray  # (n,) int32
    twist: np.ndarray  # (n, 6) float32
    length: np.ndarray  # (n,) int32 control steps
    has_start: np.ndarray  # (n,) bool: the start IK succeeded
    q_start: np.ndarray  # (n, nf) float32 start of the free joints (meaningful where has_start)


TRAJECTORIES = ("q", "qd", "p")  # the rollout's per-state outputs, (edges, steps + 1, ...)


def rollout_kernel(
    robot: Robot,
    failure: Failure,
    config: BundleConfig,
    chunk: int,
    limits: Limits | None = None,
    valid_only: bool = True,
    sharded: bool = False,
    device=None,
    sites: tuple[int, ...] | None = None,
) -> ChunkedKernel:
    """The edge rollout of `failure` over launches of `chunk` edges; inputs: (index into
    `sites`, by default the config's interaction points; start of the free joints; twist;
    length).  The joint limits (`limits`, default the robot's) are inputs of the program,
    the same program for any.  With `valid_only` the trajectories (`TRAJECTORIES`) come back
    for the valid edges only (the others never leave the device); else every edge's, whole."""
    free = failure.free(robot.nq)
    q_fixed = failure.q_fixed(robot.nq)
    limits = limits or Limits(robot.qd_max, robot.qdd_max, robot.tau_max, robot.friction)
    friction = limits.friction
    settings = config.rollout_settings()
    sites = sites or tuple(robot.interaction_points[name] for name in config.interaction_points)
    arm, inertials = robot.arm, robot.inertials

    def one(qd_max, qdd_max, tau_max, site, q0, twist, length):
        lim = Limits(qd_max, qdd_max, tau_max, friction)
        return edge_rollout(arm, inertials, lim, settings, free, q_fixed, sites, site, q0, twist, length)

    shared = [np.asarray(x, np.float32) for x in (limits.qd_max, limits.qdd_max, limits.tau_max)]
    inputs = [(np.int32, ()), (np.float32, (len(free),)), (np.float32, (6,)), (np.int32, ())]
    key = ("rollout", robot.model_hash, free, tuple(q_fixed), sites, settings, friction.tobytes())
    if not valid_only:
        return ChunkedKernel(key, one, shared, inputs, chunk, sharded=sharded, device=device)
    # only the valid edges' trajectories leave the device (about a quarter of them)
    return ChunkedKernel(key, one, shared, inputs, chunk, sharded=sharded, keep_by="valid", kept=TRAJECTORIES,
                         device=device)  # fmt: skip


class EdgeKernels:
    """The start IK and the rollout programs of one failure's edges, made once per build
    with fixed launch sizes (so every chunk reuses them).  `sharded` splits every launch
    over all devices of all processes; `device` runs them on that device alone.

    The start IK is the Reach-Ability map's own program where it can be (not sharded): the
    same sites (the TCP first, then the interaction points: an edge's point `which` is IK
    site `which + 1`), settings and launch size (`ik_chunk`, the map's), so a build
    compiles one IK program, not two.  The joint limits are inputs of the rollout, not
    constants of it: lowered limits (`limits`) reuse the program."""

    def __init__(
        self,
        robot: Robot,
        failure: Failure,
        config: BundleConfig,
        n: int,
        sharded: bool = False,
        cube_half: float = 0.025,
        device=None,
        limits: Limits | None = None,
        ik_chunk: int | None = None,
    ) -> None:
        self.robot = robot
        self.failure = failure
        self.config = config
        self.sites = tuple(robot.interaction_points[name] for name in config.interaction_points)
        self.ik_sites = (robot.tcp_site, *self.sites)
        devices = 1
        if sharded and device is None:
            from .sharding import device_count

            devices = device_count()
        per_chunk = min(config.edges_per_chunk(devices), n)
        kchunk = config.kernel_chunk()
        m = config.ik_restarts
        if sharded:  # per device: the launches of a chunk, padded to whole blocks
            ik_chunk = min(kchunk * m, -(-per_chunk * m // (1024 * devices)) * 1024)
        self.ik = IKBatch(
            robot,
            failure,
            self.ik_sites,
            default_ik_settings(iterations=config.ik_iterations, cube_half=cube_half),
            ik_chunk or default_chunk(),
            sharded=sharded,
            device=device,
        )
        roll_chunk = min(kchunk, max(1024, -(-per_chunk // (1024 * devices)) * 1024))
        self.rollout = rollout_kernel(robot, failure, config, roll_chunk, limits, sharded=sharded, device=device)

    def warm(self) -> None:
        """Compile the programs now (e.g. in a thread of its own while other work runs)."""
        self.ik.compile()
        self.rollout.compile()

    @property
    def compile_seconds(self) -> float:
        return self.ik.compile_seconds + self.rollout.compile_seconds


@dataclass
class EdgeDraws:
    """What is drawn for edges [start, stop) before their starts are solved."""

    start: int
    cell: np.ndarray  # (n, 2) reach cell (iy, ix)
    which: np.ndarray  # (n,) int32 interaction point (index into the kernels' sites)
    targets: np.ndarray  # (n, 4) x, y, z_lo, z_hi of the point's start
    q0: np.ndarray  # (n, M, nf) float32 IK restarts
    twist: np.ndarray  # (n, 6) float32
    length: np.ndarray  # (n,) int32 control steps


def draw_edges(reach: ReachResult, config: BundleConfig, robot: Robot, start: int, stop: int) -> EdgeDraws:
    """Draw edges [start, stop): cell, point, target, restarts, twist, duration (host only)."""
    failure = reach.failure
    n = stop - start
    free = list(failure.free(robot.nq))
    cells = np.argwhere(reach.labels >= NPM)  # (nc, 2) iy, ix with a solution
    if len(cells) == 0:
        raise ConfigError(f"failure {failure.spec}: no reachable cell on the task plane, so no edge can start")
    sites = tuple(robot.interaction_points[name] for name in config.interaction_points)
    radius = robot.arm.site_radius[list(sites)]
    rc = reach.config
    m = config.ik_restarts
    u = edge_uniforms(config.seed, start, stop, random_width(robot, config))
    cell = cells[np.minimum((u[:, 0] * len(cells)).astype(np.int64), len(cells) - 1)]
    which = np.minimum((u[:, 1] * len(sites)).astype(np.int32), len(sites) - 1)
    xy = np.stack([reach.xs[cell[:, 1]], reach.ys[cell[:, 0]]], axis=1) + (u[:, 2:4] - 0.5) * rc.cell
    z_lo = radius[which]
    z_hi = np.maximum(radius[which], rc.object_height + radius[which] - rc.npm_overlap)
    targets = np.concatenate([xy, z_lo[:, None], z_hi[:, None]], axis=1)
    lo, hi = robot.lower, robot.upper
    q0 = (lo + u[:, 4 : 4 + m * robot.nq].reshape(n, m, robot.nq) * (hi - lo))[:, :, free].astype(np.float32)
    rest = 4 + m * robot.nq
    direction = 2.0 * u[:, rest : rest + 6] - 1.0
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    speed = config.speed_range[0] + u[:, rest + 6] * (config.speed_range[1] - config.speed_range[0])
    twist = (direction * speed[:, None]).astype(np.float32)
    duration = config.duration_range[0] + u[:, rest + 7] * (config.duration_range[1] - config.duration_range[0])
    length = np.clip(np.round(duration / config.dt), 1, config.steps).astype(np.int32)
    return EdgeDraws(start, cell, which, targets, q0, twist, length)


def solve_starts(draws: EdgeDraws, kernels: EdgeKernels, progress: Progress | None = None) -> EdgeSamples:
    """Position-only IK for each drawn edge's start (its M restarts; the first accepted wins)."""
    n, m, nf = draws.q0.shape
    res = kernels.ik.solve(
        np.repeat(draws.targets, m, axis=0),
        np.repeat(draws.which + 1, m),  # the IK sites: the TCP, then the points (EdgeKernels)
        np.zeros(n * m, bool),
        draws.q0.reshape(n * m, nf),
        progress=(lambda k: progress.update(k // m)) if progress else None,
    )
    ok = res["ok"].reshape(n, m)
    first = np.argmax(ok, axis=1)
    free = list(kernels.failure.free(kernels.robot.nq))
    q_start = res["q"].reshape(n, m, -1)[np.arange(n), first][:, free].astype(np.float32)
    return EdgeSamples(draws.start, kernels.sites, draws.cell, draws.which, draws.twist, draws.length,
                       ok.any(axis=1), q_start)  # fmt: skip


def sample_edges(
    reach: ReachResult,
    config: BundleConfig,
    robot: Robot,
    start: int,
    stop: int,
    kernels: EdgeKernels,
    progress: Progress | None = None,
) -> EdgeSamples:
    """Sample edges [start, stop) (cell, point, target, twist, duration) and solve their starts."""
    return solve_starts(draw_edges(reach, config, robot, start, stop), kernels, progress)


def roll_out(
    samples: EdgeSamples, kernels: EdgeKernels, progress: Progress | None = None
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Roll out the sampled edges that have a start; returns their indices (sampling order)
    and the kernel's per-edge results in that order.  The trajectories (`TRAJECTORIES`) are
    kept for the valid edges only (row j: the j-th valid edge in sampling order): the
    invalid ones' never leave the device (`ChunkedKernel`'s `kept`), so a chunk holds in
    memory about a quarter of what the kernel computes."""
    idx = np.nonzero(samples.has_start)[0]
    # Longest first, so that each launch's loop stops with edges of about its own length.
    idx = idx[np.argsort(-samples.length[idx], kind="stable")]

    def in_sampling_order(keep: np.ndarray) -> np.ndarray:
        """Where each kept trajectory (in launch order) goes: its rank in sampling order."""
        rank = np.zeros(len(samples.which), np.int64)
        rank[idx[keep]] = 1
        rank = np.cumsum(rank) - 1
        return rank[idx[keep]]

    out = kernels.rollout.run(
        samples.which[idx],
        samples.q_start[idx],
        samples.twist[idx],
        samples.length[idx],
        progress=progress.update if progress else None,
        kept_dest=in_sampling_order,  # trajectories land in sampling order, copied once
    )
    back = np.argsort(idx, kind="stable")  # to sampling order
    return idx[back], {k: v if k in TRAJECTORIES else v[back] for k, v in out.items()}


def split_rolled(
    samples: EdgeSamples, idx: np.ndarray, rolled: dict[str, np.ndarray], a: int, b: int
) -> tuple[EdgeSamples, np.ndarray, dict[str, np.ndarray]]:
    """The part of a rolled-out chunk (`roll_out`'s results) that covers sampled edges
    [a, b): what `pack_chunk` would have been given had [a, b) been a chunk of its own."""
    lo, hi = a - samples.start, b - samples.start
    sub = EdgeSamples(a, samples.sites, *(getattr(samples, f)[lo:hi] for f in
                      ("cell", "which", "twist", "length", "has_start", "q_start")))  # fmt: skip
    i0, i1 = np.searchsorted(idx, [lo, hi])  # idx is in sampling order
    valid = rolled["valid"].astype(bool)
    v0, v1 = int(valid[:i0].sum()), int(valid[:i1].sum())  # trajectories: valid edges only
    part = {k: v[v0:v1] if k in TRAJECTORIES else v[i0:i1] for k, v in rolled.items()}
    return sub, idx[i0:i1] - lo, part


# ---------------------------------------------------------------------------- one chunk


@dataclass
class EdgeChunk:
    """The valid edges of sampled edges [start, stop), packed, with their index entries."""

    start: int
    stop: int
    length: np.ndarray  # (E,) int32 states per edge
    q: np.ndarray  # (S, nq) float32
    qd: np.ndarray  # (S, nq) float32
    p: np.ndarray  # (S, 3) float32
    twist: np.ndarray  # (E, 6) float32
    duration: np.ndarray  # (E,) float32
    site: np.ndarray  # (E,) int16
    start_cell: np.ndarray  # (E, 2) int32
    min_manipulability: np.ndarray  # (E,) float32
    peak_torque_ratio: np.ndarray
    peak_velocity_ratio: np.ndarray
    peak_acceleration_ratio: np.ndarray
    index_cell: np.ndarray  # (K,) int32 reach cell iy * nx + ix
    index_edge: np.ndarray  # (K,) int32 edge number within this chunk; pairs unique, sorted by (cell, edge)
    rejected: np.ndarray  # (len(REASONS) + 1,) int64: ik, then REASONS[1:]
    rolled_out: int  # edges with a start
    states_evaluated: int
    seconds: dict = field(default_factory=dict)  # sample / ik / rollout / pack

    ARRAYS = (
        "length", "q", "qd", "p", "twist", "duration", "site", "start_cell", "min_manipulability",
        "peak_torque_ratio", "peak_velocity_ratio", "peak_acceleration_ratio", "index_cell", "index_edge", "rejected",
    )  # fmt: skip

    @property
    def n_edges(self) -> int:
        return len(self.length)


def reasons() -> tuple[str, ...]:
    """The rejection reasons a chunk counts, in order."""
    return (IK_FAILED, *REASONS[1:])


def process_chunk(
    reach: ReachResult,
    config: BundleConfig,
    robot: Robot,
    start: int,
    stop: int,
    kernels: EdgeKernels,
    progress: Progress | None = None,
) -> EdgeChunk:
    """Sample, solve and roll out edges [start, stop); pack the valid ones."""
    t0 = time.perf_counter()
    samples = sample_edges(reach, config, robot, start, stop, kernels, progress)
    t1 = time.perf_counter()
    idx, out = roll_out(samples, kernels, progress)
    if progress is not None:
        progress.update(stop - start - len(idx))
    t2 = time.perf_counter()
    chunk = pack_chunk(reach, config, robot, samples, idx, out)
    chunk.seconds = {"sample_ik": t1 - t0, "rollout": t2 - t1, "pack": time.perf_counter() - t2}
    return chunk


def pack_chunk(
    reach: ReachResult, config: BundleConfig, robot: Robot, samples: EdgeSamples, idx: np.ndarray, out: dict
) -> EdgeChunk:
    """The valid edges of a rolled-out chunk, flat, with their spatial-index entries."""
    free = list(reach.failure.free(robot.nq))
    n = len(samples.which)
    valid_local = out["valid"].astype(bool)
    keep = idx[valid_local]
    rejected = np.zeros(len(REASONS), np.int64)
    rejected[0] = n - len(idx)
    for code in range(1, len(REASONS)):
        rejected[code] = int(np.sum(out["reason"][~valid_local] == code))
    lens = (samples.length[keep] + 1).astype(np.int32)  # states per edge
    # the stored states: each valid edge's first `lens` steps (roll_out's trajectories are the
    # valid edges' only), as flat rows of the (edge, step) arrays (a take beats 2-D indexing)
    flat = np.flatnonzero(np.arange(out["q"].shape[1])[None, :] < lens[:, None])
    assert len(flat) == lens.sum(), "an edge longer than its rolled-out trajectory"

    def rows_of(a: np.ndarray) -> np.ndarray:
        return np.take(a.reshape(-1, a.shape[-1]), flat, axis=0)

    q_fixed = reach.failure.q_fixed(robot.nq).astype(np.float32)
    q = np.broadcast_to(q_fixed, (len(flat), robot.nq)).copy()
    qd = np.zeros((len(flat), robot.nq), np.float32)
    q[:, free] = rows_of(out["q"])
    qd[:, free] = rows_of(out["qd"])
    p = rows_of(out["p"]).astype(np.float32)
    index_cell, index_edge = arm_index_pairs(reach, robot, q, lens, config.index_height)
    evaluated = int(np.sum(np.where(out["valid"], samples.length[idx], out["fail_step"]) + 1))
    return EdgeChunk(
        start=samples.start,
        stop=samples.start + n,
        length=lens,
        q=q,
        qd=qd,
        p=p,
        twist=samples.twist[keep],
        duration=(samples.length[keep] * config.dt).astype(np.float32),
        site=np.array(samples.sites, np.int16)[samples.which[keep]],
        start_cell=samples.cell[keep].astype(np.int32),
        min_manipulability=out["min_manipulability"][valid_local].astype(np.float32),
        peak_torque_ratio=out["peak_torque_ratio"][valid_local].astype(np.float32),
        peak_velocity_ratio=out["peak_velocity_ratio"][valid_local].astype(np.float32),
        peak_acceleration_ratio=out["peak_acceleration_ratio"][valid_local].astype(np.float32),
        index_cell=index_cell,
        index_edge=index_edge,
        rejected=rejected,
        rolled_out=len(idx),
        states_evaluated=evaluated,
    )


# States whose capsules are computed at a time when indexing (bounds the host memory a
# chunk's index needs: about 100 MB for the Panda).
INDEX_STATES = 1 << 16
_ENDS: dict[tuple[str, int], Any] = {}  # (model hash, chunk) -> its capsule-ends program
_ENDS_LOCK = threading.Lock()


def capsule_ends_kernel(robot: Robot, chunk: int | None = None):
    """jit(vmap(capsule_ends)) for `robot`, one per process and chunk (shared by the packing
    threads).  `chunk`: configurations per call (default: 32,768 on an accelerator, 1,024 on
    the CPU, for the map's index; the planner's checks on the CPU hold a few dozen and ask
    for a smaller one, `actions.SMALL_CHUNK`)."""
    from .kernels.collision import capsule_ends

    if chunk is None:
        chunk = 1 << 15 if backend() != "cpu" else 1024
    with _ENDS_LOCK:
        if (robot.model_hash, chunk) not in _ENDS:

            def one(q):
                return capsule_ends(robot.arm, q)

            _ENDS[robot.model_hash, chunk] = ChunkedKernel(
                ("capsule_ends", robot.model_hash), one, [], [(np.float32, (robot.nq,))], chunk
            )
        return _ENDS[robot.model_hash, chunk]


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
    capsule's radius of its square."""
    ny, nx = reach.labels.shape
    cell = reach.config.cell
    x0 = reach.xs[0] - cell / 2
    y0 = reach.ys[0] - cell / 2
    arm = robot.arm
    caps = np.asarray(arm.table_caps)
    if len(q) == 0 or len(caps) == 0:
        return np.zeros(0, np.int32), np.zeros(0, np.int32)
    r_cap = np.asarray(arm.cap_r, np.float64)[caps]
    edge_of_row = np.repeat(np.arange(len(length), dtype=np.int64), length)
    width = max(1, len(length))
    kernel = capsule_ends_kernel(robot)
    keys: list[np.ndarray] = []
    for s0 in range(0, len(q), INDEX_STATES):
        ends = kernel.run(np.asarray(q[s0 : s0 + INDEX_STATES], np.float32))
        a = ends["a"][:, caps].astype(np.float64)  # (m, nc, 3)
        b = ends["b"][:, caps].astype(np.float64)
        za = a[..., 2] - arm.table_z - r_cap
        zb = b[..., 2] - arm.table_z - r_cap
        row, cap = np.nonzero(np.minimum(za, zb) <= height)
        if not len(row):
            continue
        a, b, za, zb = a[row, cap], b[row, cap], za[row, cap], zb[row, cap]
        # the low stretch [t0, t1] of each axis (z falls linearly along it)
        dz = zb - za
        with np.errstate(divide="ignore", invalid="ignore"):
            t_h = np.where(np.abs(dz) > 1e-12, (height - za) / dz, 0.0)
        t0 = np.where(za <= height, 0.0, np.clip(t_h, 0.0, 1.0))
        t1 = np.where(zb <= height, 1.0, np.clip(t_h, 0.0, 1.0))
        pa = a[:, :2] + t0[:, None] * (b[:, :2] - a[:, :2])
        pb = a[:, :2] + t1[:, None] * (b[:, :2] - a[:, :2])
        k = np.ceil(np.hypot(*(pb - pa).T) / (cell / 2)).astype(np.int64) + 1  # samples per stretch
        owner = np.repeat(np.arange(len(k)), k)
        first = np.concatenate([[0], np.cumsum(k)[:-1]])
        frac = (np.arange(len(owner)) - first[owner]) / np.maximum(k[owner] - 1, 1)
        pts = pa[owner] + frac[:, None] * (pb[owner] - pa[owner])
        rad = r_cap[cap[owner]]
        edge = edge_of_row[s0 + row[owner]]
        # every cell whose square lies within the radius of a sample
        reach_cells = int(np.ceil(rad.max() / cell))
        ix = np.floor((pts[:, 0] - x0) / cell).astype(np.int64)
        iy = np.floor((pts[:, 1] - y0) / cell).astype(np.int64)
        for dy in range(-reach_cells, reach_cells + 1):
            for dx in range(-reach_cells, reach_cells + 1):
                cx, cy = ix + dx, iy + dy
                gx = np.maximum(np.abs(pts[:, 0] - (x0 + (cx + 0.5) * cell)) - cell / 2, 0.0)
                gy = np.maximum(np.abs(pts[:, 1] - (y0 + (cy + 0.5) * cell)) - cell / 2, 0.0)
                hit = (gx * gx + gy * gy <= rad * rad) & (cx >= 0) & (cx < nx) & (cy >= 0) & (cy < ny)
                keys.append(np.unique((cy[hit] * nx + cx[hit]) * width + edge[hit]))
    if not keys:
        return np.zeros(0, np.int32), np.zeros(0, np.int32)
    flat = np.unique(np.concatenate(keys))
    return (flat // width).astype(np.int32), (flat % width).astype(np.int32)


def csr(cells: np.ndarray, edges: np.ndarray, n_cells: int) -> tuple[np.ndarray, np.ndarray]:
    """CSR offsets (n_cells + 1,) and edge ids of (cell, edge) pairs sorted by cell."""
    offset = np.zeros(n_cells + 1, np.int64)
    offset[1:] = np.cumsum(np.bincount(cells, minlength=n_cells))
    return offset, edges.astype(np.int32)


# ---------------------------------------------------------------------------- in memory


def chunk_ranges(n: int, size: int, start: int = 0) -> list[tuple[int, int]]:
    return [(a, min(a + size, n)) for a in range(start, n, size)]


def build_bundle(
    reach: ReachResult,
    config: BundleConfig | None = None,
    robot: Robot | None = None,
    progress: bool = False,
    sharded: bool = False,
) -> Bundle:
    """Sample, solve and roll out the edges of `reach`'s failure, all in memory (the same
    edges `lmjx.edgestream` writes to a file in bounded memory)."""
    robot = robot or load_robot()
    config = config or BundleConfig(interaction_points=robot.default_ips)
    config.validate(robot)
    failure = reach.failure
    device = device_description()
    t_start = time.perf_counter()
    n = config.n_edges()
    kernels = EdgeKernels(
        robot, failure, config, n, sharded, reach.config.object_height / 2, ik_chunk=reach.config.chunk
    )
    bar = Progress(total=2 * n, desc=f"edges {failure.spec}", enabled=progress, unit="edge")
    chunks = [
        process_chunk(reach, config, robot, a, b, kernels, bar)
        for a, b in chunk_ranges(n, config.edges_per_chunk(1 if not sharded else _devices()))
    ]
    bar.close()
    seconds = time.perf_counter() - t_start - kernels.compile_seconds
    return pack(config, reach, chunks, n, kernels, seconds, device)


def _devices() -> int:
    from .sharding import device_count

    return device_count()


def pack(
    config: BundleConfig,
    reach: ReachResult,
    chunks: list[EdgeChunk],
    n: int,
    kernels: EdgeKernels,
    seconds: float,
    device: str,
) -> Bundle:
    """One `Bundle` of consecutive chunks (edge ids and rows renumbered)."""
    lens = np.concatenate([c.length for c in chunks])
    offset = np.zeros(len(lens), np.int64)
    if len(lens):
        offset[1:] = np.cumsum(lens)[:-1]
    first_edge = np.cumsum([0, *(c.n_edges for c in chunks)])[:-1]
    cells = np.concatenate([c.index_cell for c in chunks])
    edges = np.concatenate([c.index_edge + e0 for c, e0 in zip(chunks, first_edge, strict=True)])
    order = np.lexsort((edges, cells))
    index_offset, index_edges = csr(cells[order], edges[order], reach.labels.size)
    rejected = np.sum([c.rejected for c in chunks], axis=0)
    q = np.concatenate([c.q for c in chunks])
    return Bundle(
        config=config,
        failure=reach.failure,
        offset=offset,
        length=lens,
        q=q,
        qd=np.concatenate([c.qd for c in chunks]),
        p=np.concatenate([c.p for c in chunks]),
        q_start=q[offset] if len(offset) else np.zeros((0, q.shape[1]), np.float32),
        twist=np.concatenate([c.twist for c in chunks]),
        duration=np.concatenate([c.duration for c in chunks]),
        site=np.concatenate([c.site for c in chunks]),
        start_cell=np.concatenate([c.start_cell for c in chunks]),
        min_manipulability=np.concatenate([c.min_manipulability for c in chunks]),
        peak_torque_ratio=np.concatenate([c.peak_torque_ratio for c in chunks]),
        peak_velocity_ratio=np.concatenate([c.peak_velocity_ratio for c in chunks]),
        peak_acceleration_ratio=np.concatenate([c.peak_acceleration_ratio for c in chunks]),
        index_offset=index_offset,
        index_edges=index_edges,
        sampled=n,
        rejected={r: int(k) for r, k in zip(reasons(), rejected, strict=True)},
        seconds=seconds,
        compile_seconds=kernels.compile_seconds,
        rollout_seconds=kernels.rollout.kernel_seconds,
        edge_steps=sum(c.rolled_out for c in chunks) * config.steps,
        states_evaluated=sum(c.states_evaluated for c in chunks),
        device=device,
    )
