"""Batched IK entry point: jit + vmap of the IK kernels, run over fixed-size chunks.

`IKBatch` feeds flat batches of problems to a compiled program, padded to the chunk size so
that the program compiles once.  Programs are cached per (free joints, lock angles unless
traced, candidate sites, settings, chunk): with `traced_locks` the lock angles are inputs,
so a sweep over lock angles compiles once.  It owns no algorithm: `lmjx.reach` decides what
to solve.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from .failure import Failure
from .kernels.ik import IKSettings, ik_check, ik_solve
from .robot import Robot

_COMPILED: dict[tuple, Callable] = {}


def backend() -> str:
    """'gpu', 'cpu', ... : the platform JAX computes on."""
    return jax.default_backend()


def device_description() -> str:
    dev = jax.devices()[0]
    kind = getattr(dev, "device_kind", "") or ""
    return f"{dev.platform}" + (f" ({kind})" if kind and dev.platform != "cpu" else "")


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
    """

    robot: Robot
    failure: Failure
    sites: tuple[int, ...]
    settings: IKSettings
    chunk: int
    traced_locks: bool = False
    compile_seconds: float = 0.0
    kernel_seconds: float = 0.0  # time in kernel calls and transfers, compilation excluded
    _fn: Callable | None = field(default=None, repr=False)

    @property
    def free(self) -> tuple[int, ...]:
        return self.failure.free(self.robot.nq)

    def _key(self) -> tuple:
        locks = None if self.traced_locks else tuple(self.failure.q_fixed(self.robot.nq))
        return (self.robot.model_hash, self.free, locks, self.sites, self.settings, self.chunk)

    def _build(self) -> Callable:
        key = self._key()
        if key in _COMPILED:
            return _COMPILED[key]
        arm, settings, sites = self.robot.arm, self.settings, self.sites
        free = self.free

        def one(q_fixed, target, site, pm, q0):
            q = ik_solve(arm, settings, free, q_fixed, sites, target, site, pm, q0)
            return ik_check(arm, settings, free, q_fixed, sites, target, site, pm, q)

        c, nq = self.chunk, self.robot.nq
        t0 = time.perf_counter()
        # numpy inputs: a jnp.zeros of a new shape would itself compile a small program.
        dummy = tuple(
            jnp.asarray(a)
            for a in (
                np.zeros((c, 4), np.float32),
                np.zeros((c,), np.int32),
                np.zeros((c,), np.bool_),
                np.zeros((c, len(free)), np.float32),
            )
        )
        if self.traced_locks:
            fn = jax.jit(jax.vmap(one, in_axes=(None, 0, 0, 0, 0)))
            locks = jnp.asarray(np.zeros(nq, np.float32))
            compiled = fn.lower(locks, *dummy).compile()
            jax.block_until_ready(compiled(locks, *dummy))
        else:
            q_fixed = self.failure.q_fixed(nq)
            fn = jax.jit(jax.vmap(lambda *a: one(q_fixed, *a)))
            compiled = fn.lower(*dummy).compile()
            jax.block_until_ready(compiled(*dummy))
        # (one warm-up call is counted with the compilation: it loads the program onto the
        # device, so that the timed calls measure steady-state work)
        self.compile_seconds = time.perf_counter() - t0
        _COMPILED[key] = compiled
        return compiled

    def _call(self, *args: jnp.ndarray):
        assert self._fn is not None
        if self.traced_locks:
            return self._fn(jnp.asarray(self.failure.q_fixed(self.robot.nq).astype(np.float32)), *args)
        return self._fn(*args)

    def solve(
        self,
        targets: np.ndarray,
        site: np.ndarray,
        pm: np.ndarray,
        q0: np.ndarray,
        progress: Callable[[int], None] | None = None,
    ) -> dict[str, np.ndarray]:
        """Solve a flat batch.

        Args:
          targets: (n, 4) x, y, z_lo, z_hi.
          site: (n,) index into `sites`.
          pm: (n,) prehensile flag.
          q0: (n, nf) initial free joint angles.
          progress: called with the number of problems finished after each chunk.
        Returns:
          numpy arrays over the batch: ok, q (n, nq), pos_err, tool_z, table, self, cube.
        """
        if self._fn is None:
            self._fn = self._build()
        t0 = time.perf_counter()
        n = len(targets)
        c = self.chunk
        outs: list[dict[str, np.ndarray]] = []
        for start in range(0, n, c):
            stop = min(start + c, n)
            pad = c - (stop - start)

            def chunk_of(
                a: np.ndarray, dtype: type, start: int = start, stop: int = stop, pad: int = pad
            ) -> jnp.ndarray:
                part = np.asarray(a[start:stop], dtype=dtype)
                if pad:
                    part = np.concatenate([part, np.repeat(part[-1:], pad, axis=0)], axis=0)
                return jnp.asarray(part)

            res = self._call(
                chunk_of(targets, np.float32),
                chunk_of(site, np.int32),
                chunk_of(pm, np.bool_),
                chunk_of(q0, np.float32),
            )
            outs.append({k: np.asarray(v)[: stop - start] for k, v in res._asdict().items()})
            if progress is not None:
                progress(stop - start)
        self.kernel_seconds += time.perf_counter() - t0
        if not outs:
            nq = self.robot.nq
            return {
                "ok": np.zeros(0, bool),
                "q": np.zeros((0, nq), np.float32),
                **{k: np.zeros(0, np.float32) for k in ("pos_err", "tool_z", "table", "self", "cube")},
            }
        return {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}
