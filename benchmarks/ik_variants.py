"""Time variants of the IK kernel (XLA materialization hints, batch sizes) on one device.

    python benchmarks/ik_variants.py [--sizes 1048576] [--iterations 48]

Prints one line per variant: solves/s for the solve kernel alone, compile time apart,
median of 5 runs.  Used to choose IKSettings.materialize per platform.
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from kernels.ik import IKSettings, ik_check, ik_solve
from lmjx.bench.bench import plane_targets
from lmjx.model.failure import parse_failure
from lmjx.model.robot import load_robot
from lmjx.reach.reachability import ReachConfig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", default="1048576")
    ap.add_argument("--iterations", type=int, default=48)
    ap.add_argument("--failures", default="none,case2")
    args = ap.parse_args()
    robot = load_robot()
    print(f"device {jax.devices()[0]}, jax {jax.__version__}")
    for spec in args.failures.split(","):
        failure = parse_failure(spec, robot)
        free, q_fixed = failure.free(), failure.q_fixed()
        for b in (int(s) for s in args.sizes.split(",")):
            rng = np.random.default_rng(0)
            tgt = jnp.asarray(plane_targets(b, ReachConfig()), jnp.float32)
            lo, hi = robot.lower[list(free)], robot.upper[list(free)]
            q0 = jnp.asarray(lo + rng.random((b, len(free))) * (hi - lo), jnp.float32)
            site = jnp.zeros(b, jnp.int32)
            pm = jnp.ones(b, bool)
            args_in = (tgt, site, pm, q0)
            for mat in (0, 1, 3):
                s = IKSettings(iterations=args.iterations, materialize=mat)
                rate, med, comp = _time_kernel(
                    lambda t, si, p, q, s=s, f=free, qf=q_fixed: ik_solve(
                        robot.arm, s, f, qf, (robot.tcp_site,), t, si, p, q
                    ),
                    args_in,
                )
                print(
                    f"{spec:6s} batch {b:>9,} materialize {mat}: {rate / 1e6:8.2f} M solves/s "
                    f"({med * 1e3:.2f} ms, {args.iterations} it, compile {comp:.1f} s)",
                    flush=True,
                )
            for unroll in (False, True):
                s = IKSettings(iterations=args.iterations, unroll_checks=unroll)
                rate, med, comp = _time_kernel(
                    lambda t, si, p, q, s=s, f=free, qf=q_fixed: (
                        ik_check(robot.arm, s, f, qf, (robot.tcp_site,), t, si, p, q).ok
                    ),
                    args_in,
                )
                print(
                    f"{spec:6s} batch {b:>9,} checks only, unroll {unroll}: {rate / 1e6:8.2f} M checks/s "
                    f"({med * 1e3:.2f} ms, compile {comp:.1f} s)",
                    flush=True,
                )


def _time_kernel(one, args_in: tuple, repeats: int = 5) -> tuple[float, float, float]:
    """Compile jit(vmap(one)) on `args_in`; return (items/s, median seconds, compile seconds)."""
    fn = jax.jit(jax.vmap(one))
    t0 = time.perf_counter()
    c = fn.lower(*args_in).compile()
    comp = time.perf_counter() - t0
    c(*args_in).block_until_ready()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        c(*args_in).block_until_ready()
        ts.append(time.perf_counter() - t0)
    med = statistics.median(ts)
    return len(args_in[0]) / med, med, comp


if __name__ == "__main__":
    main()
