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

from lmjx.edges.sampling import TRAJECTORIES, EdgeKernels, sample_edges
from lmjx.mapfile.bundle import BundleConfig
from lmjx.model.robot import load_robot
from lmjx.reach.reachability import reach_config, reach_map


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


def _fresh(rows: int, devices) -> list[jax.Array]:
    """New device arrays (JAX keeps an array's host copy once made: each copy needs new ones)."""
    out = [jax.device_put(np.full((rows, 101, 13), 1.5, np.float32), d) for d in devices]
    jax.block_until_ready(out)
    return out


def _threads(fn, items) -> float:
    """Seconds for fn(item) on every item at once, a thread each."""
    t0 = time.perf_counter()
    threads = [threading.Thread(target=fn, args=(x,)) for x in items]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return time.perf_counter() - t0


def _copies(rows: int) -> dict:
    """GB/s off the devices by several means, for arrays of (rows, 101, 13) float32 (the
    shape of a launch's trajectories): np.asarray from one device and from every device at
    once (a thread each), the same after copy_to_host_async, in 16 pieces, into pinned host
    memory (`memory_kind="pinned_host"`) then to numpy, torch through DLPack into a pinned
    buffer (the link's ceiling), and host memory copies into fresh and reused buffers."""
    devs = jax.devices()
    res: dict = {}

    def rate(arrs, seconds) -> float:
        return round(sum(a.nbytes for a in arrs) / seconds / 1e9, 3)

    def asarray_all(arrs) -> float:
        return rate(arrs, _threads(lambda a: np.asarray(a), arrs))

    _ = asarray_all(_fresh(rows, devs[:1]))  # warm-up
    res["asarray_one"] = asarray_all(_fresh(rows, devs[:1]))
    res["asarray_all"] = asarray_all(_fresh(rows, devs))

    def async_all(arrs) -> float:
        t0 = time.perf_counter()
        for a in arrs:
            a.copy_to_host_async()
        for a in arrs:
            np.asarray(a)
        return rate(arrs, time.perf_counter() - t0)

    res["async_then_asarray_all"] = async_all(_fresh(rows, devs))
    res["pieces16_async_all"] = async_all([p for _ in range(16) for p in _fresh(rows // 16, devs)])
    try:
        from jax.sharding import SingleDeviceSharding

        arrs = _fresh(rows, devs)
        t0 = time.perf_counter()
        pinned = [jax.device_put(a, SingleDeviceSharding(a.devices().pop(), memory_kind="pinned_host")) for a in arrs]
        jax.block_until_ready(pinned)
        t1 = time.perf_counter()
        for a in pinned:
            np.asarray(a)
        t2 = time.perf_counter()
        res["pinned_host_put_all"] = rate(arrs, t1 - t0)
        res["pinned_host_to_numpy"] = rate(arrs, t2 - t1)
    except Exception as e:
        res["pinned_host_error"] = repr(e)[:200]
    try:
        import torch

        arrs = _fresh(rows, devs)
        bufs = [torch.empty(a.shape, dtype=torch.float32, pin_memory=True) for a in arrs]
        t0 = time.perf_counter()
        for a, b in zip(arrs, bufs, strict=True):
            b.copy_(torch.from_dlpack(a), non_blocking=True)
        torch.cuda.synchronize()
        for i in range(len(arrs)):
            torch.cuda.synchronize(i)
        res["torch_pinned_all"] = rate(arrs, time.perf_counter() - t0)
    except Exception as e:
        res["torch_error"] = repr(e)[:200]
    src = np.full((rows, 101, 13), 1.5, np.float32)
    t0 = time.perf_counter()
    dst = np.empty_like(src)
    dst[...] = src
    t1 = time.perf_counter()
    dst[...] = src
    t2 = time.perf_counter()
    res["host_copy_fresh"] = rate([src], t1 - t0)
    res["host_copy_reused"] = rate([src], t2 - t1)
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--edges", type=int, default=1_000_000)
    ap.add_argument("--copies-only", action="store_true", help="only the copy rates")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    robot = load_robot()
    reach = reach_map("case2", reach_config(robot), robot=robot)
    config = BundleConfig(edges=args.edges)
    report: dict = {"edges": args.edges, "device": str(jax.devices()[0].device_kind), "devices": jax.device_count()}
    samples = None
    for sharded in () if args.copies_only else (False, True):
        kernels = EdgeKernels(robot, reach.failure, config, sharded=sharded)
        if samples is None:
            samples = sample_edges(reach, config, robot, 0, args.edges, kernels)
        kernels.rollout.compile()
        launches = _inputs(samples, kernels.rollout)
        secs = _compute_seconds(kernels.rollout, launches)
        name = "all_devices" if sharded else "one_device"
        report[name] = {"launches": len(launches), "chunk": kernels.rollout.chunk, "compute_s": round(secs, 4)}
        print(name, report[name], flush=True)
        if sharded:
            report["compute_speedup"] = round(report["one_device"]["compute_s"] / secs, 3)
    # copies, with glibc's default allocator and then as lmjx's commands set it
    report["copy_GBps"] = _copies(65536)
    from lmjx.runtime.hostmem import return_large_buffers

    return_large_buffers()
    report["copy_GBps_mmap_1MB"] = _copies(65536)
    print(json.dumps(report["copy_GBps"]), json.dumps(report["copy_GBps_mmap_1MB"]), flush=True)
    report["trajectories"] = list(TRAJECTORIES)
    print(json.dumps(report))
    if args.out:
        with open(args.out, "w") as fh:
            json.dump(report, fh, indent=2)


if __name__ == "__main__":
    main()
