"""The push counts a map stores (`/edges/push`), summed chunk by chunk while `lmjx build-map`
writes the map, instead of read back from the whole file at its end.

A scenario's count over a reach cell is the number of the map's edges that push toward the
goal there (`pushfield.push_pairs`): a sum over edges, each edge's part depending on its
own states alone.  The build's packers (`lmjx.edges.mapwriter`) hand every packed chunk's
valid edges to `BuildPushCounts.add` while the states are in memory; the chunk's push
samples (`pushsamples.push_samples`) and each built-in scenario's pass over them
(`pushfield._group_hits`) are those of the same edges in the whole map, so the summed counts
are the whole map's, bit for bit (tests/test_pushfield.py compares them with the
reference's).  At the end only the keys are computed from the file (`entries`: they hash
the map's per-edge arrays), so neither the states nor the index are read again.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import h5py
import numpy as np

from lmjx.mapfile.bundle import Bundle, BundleConfig
from lmjx.mapfile.pushmap import (
    HEIGHT,
    MAX_ANGLE,
    FixedCut,
    StoredCounts,
    _group_hits,
    counts_key,
    fixed_cut,
    scenario_field,
)
from lmjx.mapfile.pushsamples import push_samples
from lmjx.mapfile.schema import config_from_attrs
from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.reach.reachability import ReachResult
from lmjx.runtime.devices import next_device
from lmjx.sim.scenarios import SCENARIOS, TASK_SETS, scenario


@dataclass(frozen=True)
class ChunkStates:
    """A chunk's valid edges as the push counts read a bundle: edge e's states are rows
    offset[e] .. offset[e] + length[e] - 1 of q."""

    offset: np.ndarray  # (E,) int64
    length: np.ndarray  # (E,) int32
    q: np.ndarray  # (S, nq) float32
    q_start: np.ndarray  # (E, nq) float32

    @classmethod
    def of(cls, length: np.ndarray, q: np.ndarray) -> ChunkStates:
        length = np.asarray(length, np.int32)
        offset = np.zeros(len(length), np.int64)
        offset[1:] = np.cumsum(length, dtype=np.int64)[:-1]
        return cls(offset, length, q, q[offset])


@dataclass(frozen=True)
class KeyedEdges:
    """What `pushfield.counts_key` reads of a map's edges: its settings and per-edge arrays
    (read from the written file, without its states or index)."""

    config: BundleConfig
    length: np.ndarray
    q_start: np.ndarray
    twist: np.ndarray
    duration: np.ndarray
    site: np.ndarray

    @classmethod
    def read(cls, edges: h5py.Group) -> KeyedEdges:
        """From a map's /edges group."""
        arrays = (edges[name][...] for name in ("length", "q_start", "twist", "duration", "site"))
        return cls(config_from_attrs(BundleConfig, dict(edges.attrs)), *arrays)


class BuildPushCounts:
    """The counts of the robot's built-in scenarios (both task sets, in `builtin_counts`'s
    order), summed over the chunks given to `add` (from any thread)."""

    def __init__(self, robot: Robot, failure: Failure, reach: ReachResult) -> None:
        self.robot, self.failure, self.reach = robot, failure, reach
        self.scenarios = [
            (tasks, number, scenario(number, robot.profile.task_scale, tasks))
            for tasks in TASK_SETS
            for number in sorted(SCENARIOS)
        ]
        self.fields = [scenario_field(robot, sc) for _, _, sc in self.scenarios]
        self._cuts: list[FixedCut | None] | None = None  # made by the first chunk (they compile programs)
        self._cuts_lock = threading.Lock()
        self._lock = threading.Lock()
        self.counts = np.zeros((len(self.scenarios), reach.labels.size), np.int64)
        self.edges = 0  # edges counted
        self.seconds = 0.0  # summed over the threads that called `add`

    def _fixed_cuts(self) -> list[FixedCut | None]:
        with self._cuts_lock:
            if self._cuts is None:
                self._cuts = [fixed_cut(self.robot, sc) for _, _, sc in self.scenarios]
            return self._cuts

    def add(self, length: np.ndarray, q: np.ndarray, workers: int = 1) -> None:
        """Count a chunk's valid edges: `length` (E,) states each, `q` (S, nq) their states
        in order.  `workers`: threads for the chunk's push samples and direction tests (the
        build's packers call it side by side, one thread each)."""
        t0 = time.perf_counter()
        states = ChunkStates.of(length, q)
        # the device part of the samples on the local devices in turn, as the index's
        samples = push_samples(self.robot, states, self.reach, HEIGHT, workers=workers,  # type: ignore[arg-type]
                               device=next_device("push"))  # fmt: skip
        cuts = self._fixed_cuts()
        counts = np.zeros_like(self.counts)
        for i, ((_, _, sc), field, cut) in enumerate(zip(self.scenarios, self.fields, cuts, strict=True)):
            hit = _group_hits(samples, self.robot, self.failure, states, sc, field, MAX_ANGLE, cut,  # type: ignore[arg-type]
                              threads=workers)  # fmt: skip
            counts[i] = np.bincount(samples.group_cell[hit], minlength=self.reach.labels.size)
        with self._lock:
            self.counts += counts
            self.edges += len(states.length)
            self.seconds += time.perf_counter() - t0

    def merge(self, counts: np.ndarray, edges: int, seconds: float) -> None:
        """Add counts summed elsewhere over `edges` other edges (a build's peer process:
        `lmjx.edges.peers`), in `seconds`."""
        counts = np.asarray(counts, np.int64)
        if counts.shape != self.counts.shape:
            raise RuntimeError(f"push counts of shape {counts.shape} added to counts of {self.counts.shape}")
        with self._lock:
            self.counts += counts
            self.edges += int(edges)
            self.seconds += float(seconds)

    def entries(self, bundle: Bundle | KeyedEdges) -> list[StoredCounts]:
        """The summed counts under the planner's keys (`counts_key` of the whole map's
        edges: `KeyedEdges.read` of the written map)."""
        if self.edges != len(bundle.length):
            raise RuntimeError(f"push counts summed over {self.edges} edges of a map of {len(bundle.length)}")
        ny, nx = self.reach.labels.shape
        return [
            StoredCounts(
                counts_key(self.robot, bundle, self.reach, sc, field),  # type: ignore[arg-type]
                number,
                tasks,
                self.counts[i].astype(np.int32).reshape(ny, nx),
            )
            for i, ((tasks, number, sc), field) in enumerate(zip(self.scenarios, self.fields, strict=True))
        ]
