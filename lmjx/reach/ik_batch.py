"""Batched IK: the IK kernels (solve, then acceptance checks) over flat batches of problems.

`IKBatch` compiles one program per (free joints, lock angles unless traced, candidate sites,
settings, chunk size); with `traced_locks` the lock angles are inputs, so a sweep over lock
angles compiles once.  It owns no algorithm: `lmjx.reach.reachability` and `lmjx.mapfile.bundle` decide what to
solve.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from kernels.ik import IKSettings, ik_check, ik_solve
from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.runtime.batching import ChunkedKernel, backend, device_description

__all__ = ["IKBatch", "backend", "default_chunk", "default_ik_settings", "device_description"]


def default_ik_settings(**kw: object) -> IKSettings:
    """Solver settings with the platform's best kernel layout: the distance searches of the
    checks are unrolled on accelerators (measured 3.4x faster on an H200) and kept as
    loops on a CPU (1.5x faster there); see benchmarks/RESULTS.md."""
    return IKSettings(unroll_checks=backend() != "cpu", **kw)  # type: ignore[arg-type]


def default_chunk() -> int:
    """Problems per kernel call: large on accelerators, cache-sized on a CPU."""
    return 1 << 19 if backend() != "cpu" else 4096


@dataclass
class IKBatch:
    """Solve and check flat batches of IK problems for one failure.

    Args:
      robot: the robot.
      failure: which joints are locked.
      sites: the sites problems may place (a problem's `site` indexes into this tuple).
      settings: solver and acceptance parameters.
      chunk: problems per kernel call.
      traced_locks: lock angles as kernel inputs rather than compiled-in constants.
      masked: every joint is solved for, and which are locked is a per-problem input (a
        0/1 mask; the locked joints' initial angles are their lock angles): one program
        for every failure (`lmjx.reach.atlas`).  `failure` is then ignored.
      sharded: split each chunk over all devices (`lmjx.runtime.sharding`); `chunk` is per device.
      device: run on this device (rather than JAX's default one); not with `sharded`.
    """

    robot: Robot
    failure: Failure
    sites: tuple[int, ...]
    settings: IKSettings
    chunk: int
    traced_locks: bool = False
    masked: bool = False
    sharded: bool = False
    device: Any = None
    _kernel: ChunkedKernel | None = field(default=None, repr=False)

    @property
    def free(self) -> tuple[int, ...]:
        if self.masked:
            return tuple(range(self.robot.nq))
        return self.failure.free(self.robot.nq)

    @property
    def compile_seconds(self) -> float:
        return self._kernel.compile_seconds if self._kernel else 0.0

    @property
    def kernel_seconds(self) -> float:
        return self._kernel.kernel_seconds if self._kernel else 0.0

    def _make(self) -> ChunkedKernel:
        arm, settings, sites, free = self.robot.arm, self.settings, self.sites, self.free

        def one(q_locks, target, site, pm, q0):
            q = ik_solve(arm, settings, free, q_locks, sites, target, site, pm, q0)
            return ik_check(arm, settings, free, q_locks, sites, target, site, pm, q)

        inputs = [(np.float32, (4,)), (np.int32, ()), (np.bool_, ()), (np.float32, (len(free),))]
        key = ("ik", self.robot.model_hash, free, sites, settings)
        where = {"sharded": self.sharded, "device": self.device}
        if self.masked:
            q_any = np.zeros(self.robot.nq)  # every joint is "free": no angle is read from here

            def one_masked(target, site, pm, q0, mask):
                q = ik_solve(arm, settings, free, q_any, sites, target, site, pm, q0, free_mask=mask)
                return ik_check(arm, settings, free, q_any, sites, target, site, pm, q)

            inputs.append((np.float32, (len(free),)))
            return ChunkedKernel((*key, "masked"), one_masked, [], inputs, self.chunk, **where)
        q_fixed = self.failure.q_fixed(self.robot.nq)
        if self.traced_locks:
            return ChunkedKernel((*key, "traced"), one, [q_fixed.astype(np.float32)], inputs, self.chunk, **where)
        return ChunkedKernel((*key, tuple(q_fixed)), lambda *a: one(q_fixed, *a), [], inputs, self.chunk, **where)

    @property
    def kernel(self) -> ChunkedKernel:
        """The program (made on first use, compiled by `compile` or the first `solve`)."""
        if self._kernel is None:
            self._kernel = self._make()
        return self._kernel

    def compile(self) -> None:
        """Compile the program now (otherwise the first `solve` does)."""
        self.kernel.compile()

    def solve(
        self,
        targets: np.ndarray,
        site: np.ndarray,
        pm: np.ndarray,
        q0: np.ndarray,
        progress: Callable[[int], None] | None = None,
        mask: np.ndarray | None = None,
    ) -> dict[str, np.ndarray]:
        """Solve a flat batch.

        Args:
          targets: (n, 4) x, y, z_lo, z_hi.
          site: (n,) index into `sites`.
          pm: (n,) prehensile flag.
          q0: (n, nf) initial free joint angles.
          progress: called with the number of problems finished after each chunk.
          mask: (n, nq) 1/0 free joints, only with `masked` (then q0 is (n, nq)).
        Returns:
          numpy arrays over the batch: ok, q (n, nq), pos_err, tool_z, table, self, cube.
        """
        if self.masked:
            if mask is None:
                raise ValueError("a masked IKBatch needs the per-problem mask of free joints")
            return self.kernel.run(targets, site, pm, q0, mask, progress=progress)
        return self.kernel.run(targets, site, pm, q0, progress=progress)
