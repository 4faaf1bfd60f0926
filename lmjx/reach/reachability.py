"""The Reach-Ability map (paper Algorithm 1): which table cells the arm can grasp at (PM),
only push or poke (NPM), or not reach at all, for a given failure.

For every 2 cm cell of the task plane: IK for a prehensile pose at the cell's centre; on
failure, retries at targets perturbed uniformly in the disc inscribed in the cell; after
half of the k attempts, the orientation constraint is released and interaction points on
the body (hand, wrist, forearm, ...) are cycled, one per attempt, with position-only IK.
Each attempt runs M random restarts.  A cell takes the label of its first successful
attempt.  All cells are solved together: attempt by attempt ("rounds", only cells still
unlabelled go on; cheapest on a CPU) or every attempt of every cell in one batch ("batch";
one launch, best on a GPU).  Both give the first successful attempt of every cell.

Smoothing fills isolated holes: a cell is raised to a level (reachable, or PM) when at
least `fill_neighbors` of its 8 neighbours are at that level or above.  Raw and smoothed
labels are both kept; areas are cell counts times the cell area.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kernels.ik import IKSettings
from lmjx import checks
from lmjx.errors import ConfigError
from lmjx.model.failure import Failure, as_failure
from lmjx.model.robot import Robot, as_robot
from lmjx.reach.ik_batch import IKBatch, default_chunk, default_ik_settings, device_description
from lmjx.runtime.interrupt import interruptible
from lmjx.runtime.progress import Progress
from lmjx.runtime.reprs import config_repr

UNREACHABLE, NPM, PM = 0, 1, 2
MAX_ATTEMPTS = 128  # attempts per cell: a map stores each cell's first successful one as int8
LABEL_NAMES = {UNREACHABLE: "unreachable", NPM: "npm", PM: "pm"}


@dataclass(frozen=True)
class ReachConfig:
    """Everything that defines a Reach-Ability map; defaults are lmjx's documented task plane."""

    cell: float = 0.02  # cell edge [m]
    x_range: tuple[float, float] = (0.1, 1.1)  # task plane in front of the robot [m]
    y_range: tuple[float, float] = (-0.6, 0.6)
    grasp_height: float = 0.025  # PM: TCP height, the centre of a 5 cm cube [m]
    object_height: float = 0.05  # NPM: height of the object to touch [m]
    npm_overlap: float = 0.015  # NPM: the link must reach this far below the object's top [m]
    attempts: int = 10  # k: attempts per cell; the first ceil(k/2) are PM
    restarts: int = 8  # M: random IK restarts per attempt
    epsilon: float | None = None  # perturbation radius; default: half the cell
    interaction_points: tuple[str, ...] = ("hand", "wrist", "forearm")
    iterations: int = 48  # IK iterations per restart
    fill_neighbors: int = 6  # smoothing: neighbours (of 8) that fill a hole
    seed: int = 0
    strategy: str = "auto"  # 'rounds', 'batch' or 'auto' (rounds on a CPU, batch elsewhere)
    chunk: int | None = None  # problems per kernel call; default by platform
    traced_locks: bool = False  # lock angles as kernel inputs (one compile for a sweep)

    __repr__ = config_repr

    def validate(self, robot: Robot) -> None:
        if not (math.isfinite(self.cell) and 0.001 <= self.cell <= 0.5):
            raise ConfigError(f"cell size {self.cell:g} m is out of range; use 0.001 to 0.5 (default 0.02)")
        for name, (lo, hi) in (("x", self.x_range), ("y", self.y_range)):
            if not (math.isfinite(lo) and math.isfinite(hi) and hi - lo >= self.cell):
                raise ConfigError(f"task plane {name} range [{lo:g}, {hi:g}] must span at least one cell")
        if not 2 <= self.attempts <= MAX_ATTEMPTS:
            raise ConfigError(f"attempts (k) must be 2 to {MAX_ATTEMPTS} (a map stores the attempt as int8), got "
                              f"{self.attempts}")  # fmt: skip
        if self.restarts < 1:
            raise ConfigError(f"restarts must be at least 1, got {self.restarts}")
        if self.iterations < 1:
            raise ConfigError(f"iterations must be at least 1, got {self.iterations}")
        if self.epsilon is not None and not (0 <= self.epsilon <= self.cell):
            raise ConfigError(f"epsilon {self.epsilon:g} m must lie in [0, cell]")
        if not self.interaction_points:
            raise ConfigError("at least one interaction point is needed")
        for ip in self.interaction_points:
            if ip not in robot.interaction_points:
                known = ", ".join(sorted(robot.interaction_points))
                raise ConfigError(f"unknown interaction point '{ip}'; the model has: {known}")
        if self.strategy not in ("auto", "rounds", "batch"):
            raise ConfigError(f"strategy must be auto, rounds or batch, got '{self.strategy}'")
        if self.chunk is not None and self.chunk < 1:
            raise ConfigError(f"chunk must be positive, got {self.chunk}")
        if not 1 <= self.fill_neighbors <= 8:
            raise ConfigError(f"fill_neighbors must be 1..8, got {self.fill_neighbors}")
        checks.seed(self.seed)

    @property
    def n_pm(self) -> int:
        """Attempts made in PM mode before switching to NPM."""
        return (self.attempts + 1) // 2

    def grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Cell centres along x (nx,) and y (ny,)."""
        nx = math.floor((self.x_range[1] - self.x_range[0]) / self.cell + 1e-9)
        ny = math.floor((self.y_range[1] - self.y_range[0]) / self.cell + 1e-9)
        xs = self.x_range[0] + self.cell * (np.arange(nx) + 0.5)
        ys = self.y_range[0] + self.cell * (np.arange(ny) + 0.5)
        return xs, ys

    def ik_settings(self) -> IKSettings:
        return default_ik_settings(iterations=self.iterations, cube_half=self.object_height / 2)


def reach_config(robot: Robot | str | Path | None = None, **overrides) -> ReachConfig:
    """The default ReachConfig for `robot` (a Robot, a name or an MJCF's path; default the
    Panda): its default interaction points, and the task plane scaled by its `task_scale`
    (the Panda's and the UR5e's: 1, the plane above); `overrides` replace any field.

    >>> import lmjx
    >>> lmjx.reach_config("ur5e", cell=0.05)
    ReachConfig(cell=0.05)
    """
    robot = as_robot(robot)
    s = robot.profile.task_scale
    base: dict = {"interaction_points": robot.default_ips}
    if s != 1.0:
        d = ReachConfig()
        base.update(x_range=(d.x_range[0] * s, d.x_range[1] * s), y_range=(d.y_range[0] * s, d.y_range[1] * s))
    return ReachConfig(**{**base, **overrides})


@dataclass
class ReachResult:
    """A Reach-Ability map.  Arrays are indexed [iy, ix] (rows along y)."""

    failure: Failure
    config: ReachConfig
    xs: np.ndarray  # (nx,) cell centres [m]
    ys: np.ndarray  # (ny,)
    labels: np.ndarray  # (ny, nx) int8 raw labels: 0 unreachable, 1 NPM, 2 PM
    labels_smooth: np.ndarray  # (ny, nx) int8 after hole filling
    q: np.ndarray  # (ny, nx, 7) float32 accepted joint angles, NaN where unreachable
    attempt: np.ndarray  # (ny, nx) int8 first successful attempt, -1 if none
    site: np.ndarray  # (ny, nx) int16 model site index of the solution, -1 if none
    target: np.ndarray  # (ny, nx, 4) float32 solved target x, y, z_lo, z_hi, NaN if none
    pos_err: np.ndarray  # (ny, nx) float32
    seconds: float  # wall time of the map, compilation excluded
    compile_seconds: float
    kernel_seconds: float  # of which: in the IK kernels (device work and transfers)
    device: str
    problems: int  # IK problems solved (restarts counted)
    robot_hash: str
    site_names: tuple[str, ...] = field(default_factory=tuple)

    @property
    def cell_area(self) -> float:
        return self.config.cell**2

    def __repr__(self) -> str:
        a, cells = self.areas(), f"{len(self.ys)} x {len(self.xs)} cells of {self.config.cell * 100:g} cm"
        return (
            f"ReachResult({self.failure.spec!r}: {cells}, "
            f"PM {a['pm']:.3f} m^2, NPM+PM {a['npm_pm']:.3f} m^2; {self.seconds:.1f} s on {self.device})"
        )

    def areas(self, smooth: bool = True) -> dict[str, float]:
        lab = self.labels_smooth if smooth else self.labels
        a = self.cell_area
        return {"pm": float(np.sum(lab == PM) * a), "npm_pm": float(np.sum(lab >= NPM) * a)}

    def summary(self) -> dict:
        """The JSON contract of `lmjx reach`."""
        return {
            "failure": self.failure.spec,
            "locked": {f"J{j}": a for j, a in self.failure.locked},
            "cell_m": self.config.cell,
            "area_m2": {k: round(v, 6) for k, v in self.areas(smooth=True).items()},
            "area_raw_m2": {k: round(v, 6) for k, v in self.areas(smooth=False).items()},
            "plane_m2": round(len(self.xs) * len(self.ys) * self.cell_area, 6),
            "cells": int(self.labels.size),
            "problems": int(self.problems),
            "seconds": round(self.seconds, 4),
            "compile_seconds": round(self.compile_seconds, 4),
            "kernel_seconds": round(self.kernel_seconds, 4),
            "device": self.device,
            "seed": self.config.seed,
        }


def smooth_labels(labels: np.ndarray, fill_neighbors: int = 6) -> np.ndarray:
    """Fill isolated holes: raise a cell to level L when >= fill_neighbors of its 8
    neighbours are at L or above (levels: reachable, then PM).  Never lowers a cell."""
    out = labels.copy()
    for level in (NPM, PM):
        mask = labels >= level
        padded = np.pad(mask, 1, constant_values=False)
        count = sum(
            padded[1 + dy : padded.shape[0] - 1 + dy, 1 + dx : padded.shape[1] - 1 + dx].astype(np.int32)
            for dy in (-1, 0, 1)
            for dx in (-1, 0, 1)
            if dy or dx
        )
        fill = (~mask) & (count >= fill_neighbors)
        out[fill] = np.maximum(out[fill], level)
    return out


def _perturbations(rng: np.random.Generator, n: int, k: int, eps: float) -> np.ndarray:
    """(n, k, 2) offsets: none for attempt 0, uniform in the disc of radius eps after."""
    r = eps * np.sqrt(rng.random((n, k)))
    th = 2 * np.pi * rng.random((n, k))
    off = np.stack([r * np.cos(th), r * np.sin(th)], axis=-1)
    off[:, 0] = 0.0
    return off


def attempt_plan(
    robot: Robot, config: ReachConfig
) -> tuple[tuple[int, ...], np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What each of the k attempts asks for: the sites (index 0 the TCP for PM, then the
    interaction points cycled by NPM attempts), and per attempt the site, PM flag and the
    height band (z_lo, z_hi) of the target."""
    k = config.attempts
    ip_sites = [robot.interaction_points[name] for name in config.interaction_points]
    sites = (robot.tcp_site, *ip_sites)
    attempt_site = np.array([0 if a < config.n_pm else 1 + (a - config.n_pm) % len(ip_sites) for a in range(k)])
    attempt_pm = np.arange(k) < config.n_pm
    radius = robot.arm.site_radius[list(sites)]
    z_lo = np.where(attempt_pm, config.grasp_height, radius[attempt_site])
    z_hi = np.where(
        attempt_pm,
        config.grasp_height,
        np.maximum(radius[attempt_site], config.object_height + radius[attempt_site] - config.npm_overlap),
    )
    return sites, attempt_site, attempt_pm, z_lo, z_hi


def reach_ik(robot: Robot, failure: Failure, config: ReachConfig) -> IKBatch:
    """The IK program of `failure`'s Reach-Ability map (made, not compiled): the one the
    edges' starts share (`lmjx.edges.sampling.EdgeKernels`)."""
    sites = attempt_plan(robot, config)[0]
    chunk = config.chunk or default_chunk()
    return IKBatch(robot, failure, sites, config.ik_settings(), chunk, traced_locks=config.traced_locks)


@interruptible
def reach_map(
    failure: Failure | str,
    config: ReachConfig | None = None,
    robot: Robot | str | Path | None = None,
    progress: bool = False,
) -> ReachResult:
    """Compute the Reach-Ability map of `failure` (a Failure or a spec such as 'case2' or
    'J2=0.3,J4=-1.5') for `robot` (a Robot, a shipped robot's name or an MJCF's path; default
    the Panda), with `config` (default: the robot's default map, `reach_config(robot)`), as
    `lmjx reach` does.  `progress`: a bar on stderr (a terminal, or LMJX_PROGRESS=1).

    >>> import lmjx
    >>> res = lmjx.reach_map("case2", lmjx.ReachConfig(cell=0.1), robot="panda")  # coarse: seconds on a CPU
    >>> res.areas()["pm"]
    0.0
    """
    robot = as_robot(robot)
    config = config or reach_config(robot)
    failure = as_failure(failure, robot)
    config.validate(robot)
    device = device_description()  # initializes the JAX backend outside the timed region
    t_start = time.perf_counter()

    xs, ys = config.grid()
    nx, ny = len(xs), len(ys)
    n = nx * ny
    k, m = config.attempts, config.restarts
    free = failure.free(robot.nq)
    nf = len(free)
    gx, gy = np.meshgrid(xs, ys)  # (ny, nx)
    centres = np.stack([gx.ravel(), gy.ravel()], axis=-1)  # (n, 2), cell c = iy * nx + ix

    sites, attempt_site, attempt_pm, z_lo, z_hi = attempt_plan(robot, config)

    # All randomness is drawn up front from the seed, so the labels do not depend on the
    # strategy or the chunk size.
    rng = np.random.default_rng(config.seed)
    eps = config.cell / 2 if config.epsilon is None else config.epsilon
    offsets = _perturbations(rng, n, k, eps)  # (n, k, 2)
    lo, hi = robot.lower[list(free)], robot.upper[list(free)]
    q0 = (lo + rng.random((n, k, m, nf)) * (hi - lo)).astype(np.float32)  # (n, k, m, nf)

    strategy = config.strategy
    if strategy == "auto":
        strategy = "rounds" if device.startswith("cpu") else "batch"
    batch = reach_ik(robot, failure, config)

    def problems_for(cells: np.ndarray, attempts: np.ndarray) -> tuple[np.ndarray, ...]:
        """Flat problems for (cell, attempt) pairs, M restarts each, restart fastest."""
        xy = centres[cells] + offsets[cells, attempts]
        tgt = np.concatenate([xy, z_lo[attempts, None], z_hi[attempts, None]], axis=-1)
        return (
            np.repeat(tgt, m, axis=0),
            np.repeat(attempt_site[attempts], m),
            np.repeat(attempt_pm[attempts], m),
            q0[cells, attempts].reshape(-1, nf),
        )

    best_attempt = np.full(n, -1, np.int32)
    best_q = np.full((n, robot.nq), np.nan, np.float32)
    best_err = np.full(n, np.nan, np.float32)
    solved = 0
    bar = Progress(total=n * k * m if strategy == "batch" else None, desc=f"reach {failure.spec}", enabled=progress)

    def record(cells: np.ndarray, attempts: np.ndarray, res: dict[str, np.ndarray]) -> np.ndarray:
        """Keep each cell's first successful restart of the given attempt; return success per pair."""
        ok = res["ok"].reshape(-1, m)
        hit = ok.any(axis=1)
        first = np.argmax(ok, axis=1)
        rows = np.arange(len(cells)) * m + first
        new = hit & (best_attempt[cells] < 0)
        best_attempt[cells[new]] = attempts[new]
        best_q[cells[new]] = res["q"][rows[new]]
        best_err[cells[new]] = res["pos_err"][rows[new]]
        return hit

    if strategy == "batch":
        cells = np.repeat(np.arange(n), k)
        attempts = np.tile(np.arange(k), n)
        res = batch.solve(*problems_for(cells, attempts), progress=bar.update)
        solved += len(cells) * m
        # Order (cell, attempt) pairs by attempt so the first success wins.
        ok = res["ok"].reshape(n, k, m)
        hit = ok.any(axis=2)
        for a in range(k):
            take = hit[:, a] & (best_attempt < 0)
            idx = np.nonzero(take)[0]
            rows = (idx * k + a) * m + np.argmax(ok[idx, a], axis=1)
            best_attempt[idx] = a
            best_q[idx] = res["q"][rows]
            best_err[idx] = res["pos_err"][rows]
    else:
        remaining = np.arange(n)
        for a in range(k):
            if len(remaining) == 0:
                break
            bar.set_description(f"reach {failure.spec} attempt {a + 1}/{k} ({len(remaining)} cells)")
            attempts = np.full(len(remaining), a)
            res = batch.solve(*problems_for(remaining, attempts), progress=bar.update)
            solved += len(remaining) * m
            hit = record(remaining, attempts, res)
            remaining = remaining[~hit]
    bar.close()

    labels = np.where(best_attempt < 0, UNREACHABLE, np.where(best_attempt < config.n_pm, PM, NPM)).astype(np.int8)
    site_of = np.where(best_attempt >= 0, np.array(sites)[attempt_site[np.maximum(best_attempt, 0)]], -1)
    tgt = np.full((n, 4), np.nan, np.float32)
    got = best_attempt >= 0
    ga = best_attempt[got]
    tgt[got] = np.concatenate([centres[got] + offsets[np.nonzero(got)[0], ga], z_lo[ga, None], z_hi[ga, None]], axis=-1)
    labels = labels.reshape(ny, nx)
    return ReachResult(
        failure=failure,
        config=config,
        xs=xs,
        ys=ys,
        labels=labels,
        labels_smooth=smooth_labels(labels, config.fill_neighbors),
        q=best_q.reshape(ny, nx, robot.nq),
        attempt=best_attempt.reshape(ny, nx).astype(np.int8),
        site=site_of.reshape(ny, nx).astype(np.int16),
        target=tgt.reshape(ny, nx, 4),
        pos_err=best_err.reshape(ny, nx),
        seconds=time.perf_counter() - t_start - batch.compile_seconds,
        compile_seconds=batch.compile_seconds,
        kernel_seconds=batch.kernel_seconds,
        device=device,
        problems=solved,
        robot_hash=robot.model_hash,
        site_names=robot.site_names,
    )
