"""Edges in chunks: a chunk's valid edges packed with their spatial-index entries
(`EdgeChunk`), and a whole bundle built in memory from consecutive chunks (`build_bundle`;
`lmjx.edges.stream` streams the same chunks to a file in bounded memory).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from kernels.rollout import REASONS
from lmjx.edges.index import arm_index_pairs, csr
from lmjx.edges.sampling import EdgeKernels, EdgeSamples, roll_out, sample_edges
from lmjx.mapfile.bundle import Bundle, BundleConfig, reasons
from lmjx.model.robot import Robot, load_robot
from lmjx.reach.reachability import ReachResult
from lmjx.runtime.batching import device_description
from lmjx.runtime.progress import Progress


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
    edges `lmjx.edges.stream` writes to a file in bounded memory)."""
    robot = robot or load_robot()
    config = config or BundleConfig(interaction_points=robot.default_ips)
    config.validate(robot)
    failure = reach.failure
    device = device_description()
    t_start = time.perf_counter()
    n = config.n_edges()
    kernels = EdgeKernels(robot, failure, config, sharded, reach.config.object_height / 2, ik_chunk=reach.config.chunk)
    bar = Progress(total=n, desc=f"edges {failure.spec}", enabled=progress, unit="edge", steps_per_unit=2)
    chunks = [
        process_chunk(reach, config, robot, a, b, kernels, bar)
        for a, b in chunk_ranges(n, config.edges_per_chunk(1 if not sharded else _devices()))
    ]
    bar.close()
    seconds = time.perf_counter() - t_start - kernels.compile_seconds
    return pack(config, reach, chunks, n, kernels, seconds, device)


def _devices() -> int:
    from lmjx.runtime.sharding import device_count

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
