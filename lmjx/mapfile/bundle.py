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
`lmjx.edges.stream` streams chunks to a map file in bounded memory.  Either way the same seed
gives the same edges, for any chunk size and any number of devices.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from kernels.rollout import REASONS, RolloutSettings
from lmjx import checks
from lmjx.errors import ConfigError
from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.runtime.batching import backend
from lmjx.runtime.reprs import config_repr

IK_FAILED = "ik"  # an edge whose start could not be solved
_HOLD_LOCK = threading.Lock()  # (trials on threads of their own may ask at once)
# many edges' states at once (`Bundle.states`): name -> rows of all of them, in order; and
# each edge's number of states
EdgeStates = tuple[dict[str, np.ndarray], np.ndarray]
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
        (`lmjx.edges.stream`): one launch on a GPU, 32 on a CPU."""
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
        checks.seed(self.seed)

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
    # the push counts the map stores (`lmjx.mapfile.pushmap.counts_key` -> (ny, nx) counts):
    # its robot's built-in scenarios, computed when it was built; empty for a map without them
    push: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

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

    def states(self, edges: np.ndarray, names: tuple[str, ...] = ("q", "qd", "p")) -> EdgeStates:
        """The states of many edges at once: (name -> their rows concatenated in the order of
        `edges`, (len(edges),) each edge's state count).  A lazily opened map reads every
        chunk they touch in one pass (`StateReader.gather`)."""
        edges = np.asarray(edges, np.int64)
        lengths = np.asarray(self.length[edges], np.int64)
        rows = state_rows(np.asarray(self.offset[edges], np.int64), lengths)
        return {name: take_rows(getattr(self, name), rows) for name in names}, lengths

    def hold(self, names: tuple[str, ...] = ("q",)) -> None:
        """Keep the states `names` of a lazily opened map in memory from now on (read at once,
        every chunk decompressed on all cores): a planner reads those of tens of thousands of
        edges per decision.  Nothing changes for states already in memory."""
        with _HOLD_LOCK:
            for name in names:
                data = getattr(self, name)
                if hasattr(data, "whole"):
                    setattr(self, name, data.whole())

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


def take_rows(data: Any, rows: np.ndarray) -> np.ndarray:
    """Rows `rows` of a state array: a numpy array, a `StateReader` (its `gather`) or an
    HDF5 dataset (read in increasing order, each row once)."""
    if hasattr(data, "gather"):
        return data.gather(rows)
    if isinstance(data, np.ndarray):
        return data[rows]
    unique, inverse = np.unique(rows, return_inverse=True)
    return np.asarray(data[unique] if len(unique) else data[:0])[inverse]


def state_rows(first: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The rows first[i] .. first[i] + lengths[i] - 1 of every i, concatenated in order."""
    lengths = np.asarray(lengths, np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]) if len(lengths) else np.zeros(0, np.int64)
    return np.repeat(np.asarray(first, np.int64) - starts, lengths) + np.arange(int(lengths.sum()))


def reasons() -> tuple[str, ...]:
    """The rejection reasons a chunk counts, in order."""
    return (IK_FAILED, *REASONS[1:])
