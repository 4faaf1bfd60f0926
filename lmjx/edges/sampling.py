"""Sampling and rolling out edges: each edge's draws (a reach cell, an interaction point, a
target in the cell, IK restarts, a twist and a duration: row i of a counter-based stream, so
an edge is the same whatever range it is drawn in), its start solved by position-only IK,
and the rollout kernel run over launches of fixed size (`EdgeKernels`: one set of programs
per build, the same for builds of any size and seed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kernels.rollout import Limits, edge_rollout
from lmjx.errors import ConfigError
from lmjx.mapfile.bundle import BundleConfig
from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.reach.ik_batch import IKBatch, default_chunk, default_ik_settings
from lmjx.reach.reachability import NPM, ReachResult
from lmjx.runtime.batching import ChunkedKernel
from lmjx.runtime.progress import Progress


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


def launch_sizes(config: BundleConfig, sharded: bool = False) -> tuple[int | None, int]:
    """(start IK problems, rollout edges) per launch and device: the launch sizes of a
    build's programs, set by the platform and `config.chunk` alone, so that builds of any
    edge count, seed or chunking (`build_chunk`) compile the same programs, and find them
    compiled by an earlier build on the machine (a short last launch is padded).  The IK's
    None: the Reach-Ability map's launch (its config's chunk or `default_chunk`), so that
    the edges share the map's program; sharded over processes, the restarts of a rollout
    launch's edges."""
    kchunk = config.kernel_chunk()
    return (kchunk * config.ik_restarts if sharded else None), kchunk


def sharded_launch(sharded: bool, device=None) -> bool:
    """Whether a build's launches are split over devices (`ChunkedKernel`'s `sharded`): asked
    for, on no device of its own, and over more than one device."""
    from lmjx.runtime import sharding

    return sharded and device is None and sharding.device_count() > 1


class EdgeKernels:
    """The start IK and the rollout programs of one failure's edges, made once per build
    with launch sizes that depend on neither the number of edges nor the seed
    (`launch_sizes`: every chunk of every build reuses them).  `sharded` splits every launch
    over all devices of all processes (over one device in all: the unsharded programs);
    `device` runs them on that device alone.

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
        # sharded over one device in all (a one-GPU build, sharded by default): the
        # one-device programs, so that the start IK is the reach map's program, the one the
        # presets compile for later builds (`lmjx.edges.compiling`), not one of a launch of
        # its own that no other build compiles (`sharded_launch`)
        sharded = sharded_launch(sharded, device)
        sharded_ik, roll_chunk = launch_sizes(config, sharded)
        self.ik = IKBatch(
            robot,
            failure,
            self.ik_sites,
            default_ik_settings(iterations=config.ik_iterations, cube_half=cube_half),
            sharded_ik or ik_chunk or default_chunk(),
            sharded=sharded,
            device=device,
        )
        self.rollout = rollout_kernel(robot, failure, config, roll_chunk, limits, sharded=sharded, device=device)

    def warm(self) -> None:
        """Compile the programs now (e.g. in a thread of its own while other work runs): the
        rollout first, as the IK program is often the reach map's, which a build's reach map
        loads meanwhile."""
        self.rollout.compile()
        self.ik.compile()

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


def start_cells(reach: ReachResult) -> np.ndarray:
    """(nc, 2) iy, ix of the cells edges may start from (those with a solution); ConfigError
    when there is none."""
    cells = np.argwhere(reach.labels >= NPM)
    if len(cells) == 0:
        raise ConfigError(f"failure {reach.failure.spec}: no reachable cell on the task plane, so no edge can start")
    return cells


def draw_edges(reach: ReachResult, config: BundleConfig, robot: Robot, start: int, stop: int) -> EdgeDraws:
    """Draw edges [start, stop): cell, point, target, restarts, twist, duration (host only)."""
    failure = reach.failure
    n = stop - start
    free = list(failure.free(robot.nq))
    cells = start_cells(reach)  # (nc, 2) iy, ix with a solution
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
