"""Where a streamed build's 2-GPU speed-up goes: the edge-rollout program alone on one device
and on every local device (results left on the devices), and the rate at which results come
off the devices to the host (one device, then all at once).

    python benchmarks/shard_scaling.py [--edges 1000000] [--out scaling.json]

The edges are those `lmjx build-map --failure case2` samples (seed 0), starts solved once;
each timing is the median of three passes after a warm-up pass.
"""

from __future__ import annotations

import argparse
import json
import statistics
import threading
import time

import jax
import numpy as np

from lmjx.bundle import TRAJECTORIES, BundleConfig, EdgeKernels, sample_edges
from lmjx.reach import reach_config, reach_map
from lmjx.robot import load_robot


def _inputs(samples, kernel) -> list[list]:
    """The launches of `kernel` over the edges that have a start (longest first, as roll_out)."""
    idx = np.nonzero(samples.has_start)[0]
    idx = idx[np.argsort(-samples.length[idx], kind="stable")]
    arrays = [samples.which[idx], samples.q_start[idx], samples.twist[idx], samples.length[idx]]
    c = kernel.chunk
    launches = []
    for start in range(0, len(idx), c):
        parts = []
        for a, (dtype, _) in zip(arrays, kernel.inputs, strict=True):
            part = np.asarray(a[start : start + c], dtype=dtype)
            if len(part) < c:
                part = np.concatenate([part, np.repeat(part[-1:], c - len(part), axis=0)])
            parts.append(kernel._put(part))
        launches.append(parts)
    return launches


def _compute_seconds(kernel, launches) -> float:
    def one_pass() -> float:
        t0 = time.perf_counter()
        res = [kernel._fn(*kernel.shared, *parts) for parts in launches]
        jax.block_until_ready(res)
        return time.perf_counter() - t0

    one_pass()
    return statistics.median(one_pass() for _ in range(3))


def _copy_rate(arrays: list[jax.Array]) -> float:
    """GB/s for copying `arrays` (one per device) to the host at once, a thread each."""
    out: list = [None] * len(arrays)

    def get(i: int) -> None:
        out[i] = np.asarray(arrays[i])

    t0 = time.perf_counter()
    threads = [threading.Thread(target=get, args=(i,)) for i in range(len(arrays))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return sum(a.nbytes for a in arrays) / (time.perf_counter() - t0) / 1e9


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--edges", type=int, default=1_000_000)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    robot = load_robot()
    reach = reach_map("case2", reach_config(robot), robot=robot)
    config = BundleConfig(edges=args.edges)
    report: dict = {"edges": args.edges, "device": str(jax.devices()[0].device_kind), "devices": jax.device_count()}
    samples = None
    for sharded in (False, True):
        kernels = EdgeKernels(robot, reach.failure, config, args.edges, sharded=sharded)
        if samples is None:
            samples = sample_edges(reach, config, robot, 0, args.edges, kernels)
        kernels.rollout._build()
        launches = _inputs(samples, kernels.rollout)
        secs = _compute_seconds(kernels.rollout, launches)
        name = "all_devices" if sharded else "one_device"
        report[name] = {"launches": len(launches), "chunk": kernels.rollout.chunk, "compute_s": round(secs, 4)}
        print(name, report[name], flush=True)
        if sharded:
            report["compute_speedup"] = round(report["one_device"]["compute_s"] / secs, 3)
    # copies: one launch's trajectories, from one device and from every device at once
    per_device = [jax.device_put(np.ones((131072, config.steps + 1, 5), np.float32), d) for d in jax.devices()]
    jax.block_until_ready(per_device)
    _copy_rate(per_device[:1])
    report["copy_GBps_one_device"] = round(_copy_rate(per_device[:1]), 3)
    fresh = [jax.device_put(np.ones((131072, config.steps + 1, 5), np.float32), d) for d in jax.devices()]
    jax.block_until_ready(fresh)
    report["copy_GBps_all_devices"] = round(_copy_rate(fresh), 3)
    report["trajectories"] = list(TRAJECTORIES)
    print(json.dumps(report))
    if args.out:
        with open(args.out, "w") as fh:
            json.dump(report, fh, indent=2)


if __name__ == "__main__":
    main()
