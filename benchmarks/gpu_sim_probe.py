"""Probe the GPU simulator (MuJoCo Warp) against C MuJoCo on Greedy's candidates.

Scenario 3, the park pose, candidate actions from a map: C MuJoCo `mujoco.rollout` on all
host cores (whole scene) as the reference; the GPU simulator at several batch sizes and
settings, each timed (capture apart, median of repeats) and compared with the reference;
then a per-kernel time profile of single physics steps (where the time of a step goes).

    python3 benchmarks/gpu_sim_probe.py --map maps/case2.h5 --sizes 256,1024,4096 --out probe.json

On a machine without CUDA it runs on Warp's CPU device (small --sizes and --truncate).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections import defaultdict
from dataclasses import replace

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--map", default="maps/case2.h5")
    ap.add_argument("--sizes", default="256,1024,4096")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--truncate", type=int, default=0, help="keep only the last N control points of each action")
    ap.add_argument("--variants", default="fuse,plain", help="GPU settings to try")
    ap.add_argument("--all-sizes", default="fuse", help="the variant run at every size and profiled")
    ap.add_argument("--profile", default="256,4096", help="batch sizes to profile per kernel ('' for none)")
    ap.add_argument("--out")
    args = ap.parse_args()

    import warp as wp

    from lmjx.bench.planner import candidate_actions
    from lmjx.model.robot import load_robot
    from lmjx.planner.scoring import score
    from lmjx.sim.cpu import CpuSimulator
    from lmjx.sim.gpu import GpuSimConfig, GpuSimulator

    wp.config.quiet = True
    wp.init()
    cuda = wp.get_cuda_device_count() > 0
    dev = "cuda:0" if cuda else "cpu"
    sizes = [int(s) for s in args.sizes.split(",")]
    robot = load_robot()
    t0 = time.perf_counter()
    _mf, sc, scene, objects, tp, acts = candidate_actions(robot, args.map, 3, max(sizes), 0)
    if args.truncate:
        acts = [replace(a, q=a.q[-args.truncate :], qd=a.qd[-args.truncate :]) for a in acts]
    report: dict = {
        "device": wp.get_device(dev).name if cuda else "cpu",
        "candidates_s": time.perf_counter() - t0,
        "distinct_edges": len({a.edge for a in acts}),
        "mean_points": float(np.mean([len(a.q) for a in acts])),
        "rows": [],
    }
    print(f"device {report['device']}, {len(acts)} candidates ({report['distinct_edges']} distinct edges), "
          f"{report['mean_points']:.0f} control points on average", flush=True)  # fmt: skip
    q0 = tp.park

    def save() -> None:
        if args.out:
            with open(args.out, "w") as f:
                json.dump(report, f, indent=1)

    cpu = CpuSimulator(scene)
    ref = {}
    for n in sizes:
        reps = args.repeats if n <= 1024 else 1
        times = []
        for _ in range(reps):
            t0 = time.perf_counter()
            ref[n] = cpu.simulate(q0, objects, acts[:n])
            times.append(time.perf_counter() - t0)
        row = {"sim": f"C MuJoCo {cpu.threads} threads", "n": n, "seconds": statistics.median(times)}
        report["rows"].append(row)
        print(row, flush=True)
        save()

    def agreement(n: int, final: np.ndarray) -> dict:
        finite = np.isfinite(final).all(axis=(1, 2))
        d = np.hypot(*(final[:, 0, :2] - ref[n][:, 0, :2]).T)[finite]
        s_ref = score(sc, robot, ref[n])
        s = score(sc, robot, np.where(finite[:, None, None], final, 1e3))
        return {
            "non_finite": int((~finite).sum()),
            "median_cm": float(np.median(d) * 100) if len(d) else None,
            "p90_cm": float(np.quantile(d, 0.9) * 100) if len(d) else None,
            "max_cm": float(d.max() * 100) if len(d) else None,
            "same_choice": bool(np.argmin(s) == np.argmin(s_ref)),
            "gap_cm": float((s_ref[np.argmin(s)] - s_ref.min()) * 100),
        }

    plain = GpuSimConfig(device=dev)
    variants = {  # name: (settings, scene with static bodies fused)
        "plain": (plain, False),
        "fuse": (plain, True),
        "ccd": (replace(plain, native_ccd=True), False),
        "seg8": (replace(plain, segment=8), False),
        "seg128": (replace(plain, segment=128), False),
    }
    from lmjx.sim.scene import build_scene

    fused_scene = build_scene(robot, sc, fuse_static=True)

    def profile() -> None:
        from mujoco.mjx.third_party import mujoco_warp as mjw

        sim = sims[args.all_sizes]
        for n in [int(s) for s in args.profile.split(",")]:
            sim.simulate(q0, objects, acts[:n])  # leaves the batch mid-scene, objects in contact
            b = sim._batches[sim.bucket(n)]
            per = defaultdict(float)
            count = defaultdict(int)
            steps = 5
            with wp.ScopedDevice(dev):
                wp.synchronize()
                t0 = time.perf_counter()
                with wp.ScopedTimer("steps", print=False, cuda_filter=wp.TIMING_KERNEL, synchronize=True) as t:
                    for _ in range(steps):
                        mjw.step(sim.m, b.d)
                wall = time.perf_counter() - t0
            for r in t.timing_results:
                per[r.name] += r.elapsed / steps
                count[r.name] += 1
            total = sum(per.values())
            top = sorted(per.items(), key=lambda kv: -kv[1])[:30]
            prof = {
                "n": n,
                "kernels_per_step": sum(count.values()) / steps,
                "kernel_ms_per_step": total,
                "wall_ms_per_step_ungraphed": wall / steps * 1000,
                "top": [(k, round(v, 4), count[k] // steps) for k, v in top],
            }
            report.setdefault("profile", []).append(prof)
            save()
            print(f"profile n={n}: {prof['kernels_per_step']:.0f} kernels/step, {total:.3f} ms kernel time/step, "
                      f"{prof['wall_ms_per_step_ungraphed']:.3f} ms wall/step without graphs")  # fmt: skip
            for k, v, c in prof["top"]:
                print(f"    {v:8.4f} ms  x{c:<3d} {k}")

    sims = {}
    for name in [v for v in args.variants.split(",") if v]:
        cfg, fused = variants[name]
        cfg = replace(cfg, buckets=tuple(sizes))
        t0 = time.perf_counter()
        sim = GpuSimulator(fused_scene if fused else scene, config=cfg)
        sims[name] = sim
        model_s = time.perf_counter() - t0
        for n in sizes if name == args.all_sizes else [sizes[0], sizes[-1]]:
            cap = sim.prepare(n, max(len(a.q) for a in acts))
            t0 = time.perf_counter()
            final = sim.simulate(q0, objects, acts[:n])  # first run: module loads
            first = time.perf_counter() - t0
            times = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                final = sim.simulate(q0, objects, acts[:n])
                times.append(time.perf_counter() - t0)
            b = sim._batches[sim.bucket(n)]
            row = {
                "sim": f"gpu {name}",
                "n": n,
                "model_s": round(model_s, 2),
                "capture_s": round(cap, 2),
                "first_s": round(first, 3),
                "seconds": statistics.median(times),
                "steps": int(sim.steps_run),
                "reruns": sim.reruns,
                "nacon_end": int(b.d.nacon.numpy()[0]),
                "nefc_end_max": int(b.d.nefc.numpy().max()),
                "niter_end_max": int(b.d.solver_niter.numpy().max()),
                **agreement(n, final),
            }
            report["rows"].append(row)
            print(row, flush=True)
            save()
        if name == args.all_sizes and cuda and args.profile:
            profile()

    save()
    print("rows:")
    for r in report["rows"]:
        print("  ", {k: r[k] for k in r if k in ("sim", "n", "seconds", "capture_s", "median_cm", "p90_cm",
                                                 "same_choice", "gap_cm", "non_finite", "reruns")})  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
