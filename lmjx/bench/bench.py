"""`lmjx bench`: lmjx's kernels against the baselines, side by side, in one run.

Figures (all on the same task-plane targets, PM mode: TCP at grasp height, tool down):
  * lmjx batched IK (solve only, and solve + acceptance checks) per batch size: solves/s,
    compile time apart, median of repeats; the Reach-Ability map's program (its sites,
    settings), one launch per batch;
  * pytorch_kinematics PseudoInverseIK on the same device, same batch and iteration count;
  * a serial PyBullet calculateInverseKinematics loop on PyBullet's own Panda (CPU);
  * whole Reach-Ability maps (after compilation) for none and the robot's presets (the
    Panda's case1 and case2).
Speed is measured here, never asserted in unit tests.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from lmjx.bench.baselines import BaselineMissingError, pk_chain, pybullet_ik_loop, pybullet_panda
from lmjx.errors import ConfigError, LmjxError
from lmjx.model.failure import parse_failure
from lmjx.model.robot import Robot, load_robot
from lmjx.reach.ik_batch import IKBatch, backend, default_ik_settings, device_description
from lmjx.reach.reachability import ReachConfig, attempt_plan, reach_config, reach_map
from lmjx.runtime.fileio import check_writable, write_text_atomic


def _median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def plane_targets(n: int, config: ReachConfig, seed: int = 0) -> np.ndarray:
    """n PM targets (x, y, z, z): the task plane's cell centres, repeated as needed."""
    xs, ys = config.grid()
    gx, gy = np.meshgrid(xs, ys)
    cells = np.stack([gx.ravel(), gy.ravel()], axis=-1)
    idx = np.random.default_rng(seed).permutation(np.resize(np.arange(len(cells)), n))
    z = np.full((n, 1), config.grasp_height)
    return np.concatenate([cells[idx], z, z], axis=-1)


def bench_lmjx_ik(robot: Robot, sizes: list[int], iterations: int, repeats: int) -> list[dict]:
    import jax
    import jax.numpy as jnp

    from kernels.ik import ik_solve

    failure = parse_failure("none", robot)
    cfg = reach_config(robot)
    settings = cfg.ik_settings() if iterations == cfg.iterations else default_ik_settings(iterations=iterations)
    free = failure.free()
    q_fixed = failure.q_fixed()
    sites = attempt_plan(robot, cfg)[0]  # the maps' program: every problem on the TCP, the first of its sites
    rows = []
    for b in sizes:
        rng = np.random.default_rng(1)
        tgt = plane_targets(b, cfg)
        q0 = (robot.lower + rng.random((b, robot.nq)) * (robot.upper - robot.lower)).astype(np.float32)
        args = (jnp.asarray(tgt, jnp.float32), jnp.zeros(b, jnp.int32), jnp.ones(b, bool), jnp.asarray(q0))

        solve = jax.jit(jax.vmap(lambda t, s, pm, q: ik_solve(robot.arm, settings, free, q_fixed, sites, t, s, pm, q)))
        t0 = time.perf_counter()
        solve_c = solve.lower(*args).compile()
        compile_solve = time.perf_counter() - t0
        solve_c(*args).block_until_ready()
        t_solve = _median_time(lambda: solve_c(*args).block_until_ready(), repeats)  # noqa: B023

        batch = IKBatch(robot, failure, sites, settings, chunk=b)
        batch.solve(tgt, np.zeros(b, np.int32), np.ones(b, bool), q0)
        res = {}

        def full() -> None:
            res.update(batch.solve(tgt, np.zeros(b, np.int32), np.ones(b, bool), q0))  # noqa: B023

        t_full = _median_time(full, repeats)
        rows.append(
            {
                "batch": b,
                "iterations": iterations,
                "compile_s": round(compile_solve, 3),
                "compile_with_checks_s": round(batch.compile_seconds, 3),
                "solve_s": t_solve,
                "solve_per_s": b / t_solve,
                "solve_check_s": t_full,
                "solve_check_per_s": b / t_full,
                "accepted": float(np.mean(res["ok"])),
            }
        )
    return rows


def bench_pk(robot: Robot, b: int, iterations: int, repeats: int) -> dict:
    import pytorch_kinematics as pk
    import torch

    device = "cuda" if backend() == "gpu" and torch.cuda.is_available() else "cpu"
    chain = pk_chain(robot, device=device, dtype="float32")
    limits = torch.tensor(np.stack([robot.lower, robot.upper], axis=1), dtype=torch.float32, device=device)
    tgt = plane_targets(b, reach_config(robot))
    rng = np.random.default_rng(1)
    q0 = torch.tensor(
        robot.lower + rng.random((1, robot.nq)) * (robot.upper - robot.lower), dtype=torch.float32, device=device
    )
    rot = torch.tensor([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]], device=device).expand(b, 3, 3)
    goal = pk.Transform3d(pos=torch.tensor(tgt[:, :3], dtype=torch.float32, device=device), rot=rot, device=device)
    ik = pk.PseudoInverseIK(
        chain,
        retry_configs=q0,
        joint_limits=limits,
        max_iterations=iterations,
        early_stopping_any_converged=False,
        early_stopping_no_improvement=None,
        enforce_joint_limits=False,  # its post-hoc limit refinement adds iterations
        clamp_to_limits=False,  # with clamping, 0.10.0 does not converge on these targets
        pos_tolerance=0.002,
        rot_tolerance=0.05,
    )

    def run() -> None:
        ik.clear()
        ik.solve(goal)
        if device == "cuda":
            torch.cuda.synchronize()

    t0 = time.perf_counter()
    run()
    first = time.perf_counter() - t0
    t = _median_time(run, repeats)
    sol = ik.solve(goal)
    return {
        "device": device,
        "batch": b,
        "iterations": iterations,
        "first_call_s": round(first, 3),
        "solve_s": t,
        "solve_per_s": b / t,
        "converged": float(sol.converged.float().mean()),
    }


def bench_pybullet(robot: Robot, n: int, iterations: tuple[int, ...]) -> dict:
    """PyBullet's IK loop at several iteration caps; the fastest is kept for the ratio."""
    if robot.key != "panda":
        raise BaselineMissingError(f"PyBullet ships a model of the Panda only, not of {robot.key}")
    panda = pybullet_panda()
    tgt = plane_targets(n, reach_config(robot))[:, :3]
    rng = np.random.default_rng(1)
    q0 = panda.lower + rng.random((n, len(panda.joints))) * (panda.upper - panda.lower)
    runs = []
    for it in iterations:
        seconds, success = pybullet_ik_loop(panda, tgt, q0, it)
        runs.append({"max_iterations": it, "seconds": seconds, "solve_per_s": n / seconds, "success": success})
    fastest = max(runs, key=lambda r: r["solve_per_s"])
    return {
        "device": f"cpu ({platform.machine()}, {platform.node()}), one thread",
        "solves": n,
        "runs": runs,
        "solve_per_s": fastest["solve_per_s"],
    }


def bench_maps(robot: Robot, failures: list[str], config: ReachConfig) -> list[dict]:
    rows = []
    for f in failures:
        first = reach_map(f, config, robot=robot)
        second = reach_map(f, config, robot=robot)
        rows.append(
            {
                "failure": f,
                "cell_m": config.cell,
                "cells": int(second.labels.size),
                "attempts": config.attempts,
                "restarts": config.restarts,
                "interaction_points": list(config.interaction_points),
                "problems": second.problems,
                "compile_s": round(first.compile_seconds, 3),
                "seconds": second.seconds,
                "area_m2": second.areas(True),
            }
        )
    return rows


def bench_rollouts(robot: Robot, edges: int, reference_edges: int, repeats: int, cell: float | None = None) -> dict:
    """Edge rollouts (case 2, the default edge settings) against the serial C MuJoCo loop
    doing the same computation and checks on the first `reference_edges` of the same edges
    (their starts drawn over a reach map of `cell` cells, the default when None)."""
    from lmjx.edges.rollout_ref import ReferenceRollout
    from lmjx.edges.sampling import EdgeKernels, roll_out, sample_edges
    from lmjx.mapfile.bundle import BundleConfig

    failure = bench_failure(robot)
    reach = reach_map(failure, reach_config(robot, cell=cell) if cell else reach_config(robot), robot=robot)
    config = BundleConfig(edges=edges, seed=1, build_chunk=edges, interaction_points=robot.default_ips)
    kernels = EdgeKernels(robot, reach.failure, config, ik_chunk=reach.config.chunk)
    samples = sample_edges(reach, config, robot, 0, edges, kernels)
    idx, out = roll_out(samples, kernels)  # compiles, then one run
    compile_s = kernels.rollout.compile_seconds
    t_first = kernels.rollout.kernel_seconds
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        idx, out = roll_out(samples, kernels)
        times.append(time.perf_counter() - t0)
    t = statistics.median(times)
    evaluated = int(np.sum(np.where(out["valid"], samples.length[idx], out["fail_step"]) + 1))
    nominal = len(idx) * config.steps

    ref = ReferenceRollout(robot, reach.failure, config.rollout_settings())
    sel = idx[:reference_edges]
    t0 = time.perf_counter()
    ref_states = 0
    for e in sel:
        r = ref.run(samples.sites[samples.which[e]], samples.q_start[e].astype(np.float64),
                    samples.twist[e].astype(np.float64), int(samples.length[e]))  # fmt: skip
        ref_states += len(r.q)
    t_ref = time.perf_counter() - t0
    return {
        "failure": failure,
        "edges_rolled_out": len(idx),
        "max_steps": config.steps,
        "valid": int(out["valid"].sum()),
        "compile_s": round(compile_s, 3),
        "first_run_s": round(t_first, 4),
        "seconds": t,
        "edge_steps": nominal,
        "edge_steps_per_s": nominal / t,
        "states_evaluated": evaluated,
        "states_per_s": evaluated / t,
        "reference": {
            "what": "serial C MuJoCo loop (mj_jacSite, mj_jacDot, mj_rne, contacts), one thread",
            "edges": len(sel),
            "states": ref_states,
            "seconds": t_ref,
            "states_per_s": ref_states / t_ref,
        },
        "speedup_states": (evaluated / t) / (ref_states / t_ref),
    }


def _robot_flag(robot: Robot) -> str:
    return "" if robot.key == "panda" else f" --robot {robot.key}"


def bench_failure(robot: Robot) -> str:
    """The failure the rollout and planner sections use: case2 where the robot has it."""
    presets = list(robot.profile.presets)
    return "case2" if "case2" in presets else (presets[-1] if presets else "none")


def _fmt_rate(x: float) -> str:
    return f"{x / 1e6:.2f} M/s" if x >= 1e5 else f"{x / 1e3:.1f} k/s"


def run_bench(args: argparse.Namespace) -> int:
    robot = load_robot(args.robot)
    on_gpu = backend() == "gpu"
    if args.out:
        check_writable(args.out, "benchmark results")
    if args.sizes:
        sizes = list(args.sizes)  # checked by the command's parser
    elif args.quick:
        sizes = [2048]
    else:
        sizes = [1 << 16, 1 << 20, 1 << 21] if on_gpu else [4096, 16384]
    iterations = reach_config(robot).iterations
    sections = parse_sections(args.sections)
    report: dict = {
        "date": dt.date.today().isoformat(),
        "device": device_description(),
        "command": "lmjx bench " + " ".join(sys.argv[2:]) if sys.argv[1:2] == ["bench"] else "lmjx bench",
        "python": platform.python_version(),
    }
    ratios: dict = {}
    if "ik" in sections:
        report["ik"] = bench_lmjx_ik(robot, sizes, iterations, args.repeats)
        pk_batch = min(max(sizes), 1 << 20) if not args.quick else sizes[0]
        try:
            report["pytorch_kinematics"] = bench_pk(robot, pk_batch, iterations, args.repeats)
        except (BaselineMissingError, ImportError) as e:
            report["pytorch_kinematics"] = {"skipped": str(e)}
        try:
            report["pybullet"] = bench_pybullet(robot, 50 if args.quick else 500, (20, iterations, 200))
        except (BaselineMissingError, ImportError) as e:
            report["pybullet"] = {"skipped": str(e)}
        best = max(r["solve_check_per_s"] for r in report["ik"])
        if "solve_per_s" in report["pybullet"]:
            ratios["lmjx_vs_pybullet"] = best / report["pybullet"]["solve_per_s"]
        if "solve_per_s" in report["pytorch_kinematics"]:
            same = [r for r in report["ik"] if r["batch"] == report["pytorch_kinematics"]["batch"]]
            ref = same[0]["solve_check_per_s"] if same else best
            ratios["lmjx_vs_pytorch_kinematics_same_batch"] = ref / report["pytorch_kinematics"]["solve_per_s"]
    if "maps" in sections:
        map_cfg = reach_config(robot, cell=0.05) if args.quick else reach_config(robot)
        report["maps"] = bench_maps(robot, ["none"] if args.quick else ["none", *robot.profile.presets], map_cfg)
    if "rollouts" in sections:
        n_edges = 500 if args.quick else (100_000 if on_gpu else 5_000)
        report["rollouts"] = bench_rollouts(robot, n_edges, 20 if args.quick else 100, args.repeats,
                                            cell=0.05 if args.quick else None)  # fmt: skip
        ratios["lmjx_rollouts_vs_serial_c_mujoco"] = report["rollouts"]["speedup_states"]
    if "planner" in sections:
        report["planner"] = bench_planner_decisions(robot, args)
    if "scoring" in sections:
        from lmjx.bench.planner import bench_planner
        from lmjx.planner.trial import resolve_simulator

        sim_name, why = resolve_simulator(args.sim)
        print(f"lmjx bench: simulator {sim_name} ({why})", file=sys.stderr)
        if args.candidates:
            counts = sorted(set(args.candidates))  # checked by the command's parser
        else:
            counts = [8] if args.quick else ([256, 1024, 4096] if sim_name == "gpu" else [256])
        planner_map = args.planner_map or f"{robot.maps_dir}/{bench_failure(robot)}.h5"
        if Path(planner_map).exists():
            report["scoring"] = bench_planner(robot, planner_map, counts, args.repeats, sim_name)
            report["scoring"]["simulator_reason"] = why
        else:
            build = f"lmjx build-map{_robot_flag(robot)} --failure {bench_failure(robot)}"
            report["scoring"] = {"skipped": f"no map at {planner_map} (build it with: {build})"}
        for r in report["scoring"].get("rows", []):
            if r["simulator"] == "gpu":
                ratios[f"gpu_greedy_scoring_{r['candidates']}_vs_c_mujoco_all_cores"] = r["speedup_vs_cpu"]
    if "agreement" in sections:
        report["agreement"] = bench_agreement(robot, args)
    if "build" in sections:
        from lmjx.bench.build import bench_build, build_sizes

        flag = [] if robot.key == "panda" else ["--robot", robot.key]
        report["build"] = bench_build(args.failure or bench_failure(robot), build_sizes(on_gpu, args.edges), flag)
    report["ratios"] = ratios

    if args.out:
        write_text_atomic(args.out, json.dumps(report, indent=2) + "\n")
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"lmjx bench on {report['device']}, {report['date']}")
    if "ik" in report:
        _print_ik(report, iterations)
    if "maps" in report:
        _print_maps(report)
    if "rollouts" in report:
        _print_rollouts(report)
    if "scoring" in report:
        if "skipped" in report["scoring"]:
            print(f"  Greedy scoring: skipped ({report['scoring']['skipped']})")
        else:
            _print_planner(report["scoring"])
    if "planner" in report:
        from lmjx.bench.decisions import print_decisions

        if "skipped" in report["planner"]:
            print(f"  decisions: skipped ({report['planner']['skipped']})")
        else:
            print_decisions(report["planner"])
    if "agreement" in report:
        _print_agreement(report["agreement"])
    if "build" in report:
        from lmjx.bench.build import print_build

        print_build(report["build"])
    for k, v in ratios.items():
        print(f"  {k}: {v:,.1f}x")
    return 0


def _print_agreement(ag: dict) -> None:
    if "skipped" in ag:
        print(f"  agreement: skipped ({ag['skipped']})")
        return
    d = ag["target_end_diff_m"]
    print(
        f"  agreement of {ag['simulator']} with C MuJoCo over {ag['decisions']} Greedy decisions "
        f"({ag['candidates']:,} candidates): same action {ag['same_choice'] * 100:.1f} %, same or within 1 cm "
        f"{ag['same_or_within_1cm'] * 100:.1f} %; target ends {d['median'] * 100:.2f} / {d['p90'] * 100:.2f} cm "
        f"(median / p90) apart; {ag['non_finite']} non-finite"
    )
    if "gpu_vs_gpu" in ag:
        g = ag["gpu_vs_gpu"]
        print(
            f"  the same decisions on a second GPU simulator (other batches): same or within 1 cm "
            f"{g['same_or_within_1cm'] * 100:.1f} %, target ends {g['target_end_diff_m']['median'] * 100:.2f} / "
            f"{g['target_end_diff_m']['p90'] * 100:.2f} cm apart (median / p90)"
        )


SECTIONS = ("ik", "maps", "rollouts", "scoring", "planner", "agreement", "build")


def bench_planner_decisions(robot: Robot, args: argparse.Namespace) -> dict:
    """The planner section: whole decisions of each ASM (`lmjx.bench.decisions`) on the maps of
    the robot's presets found in --maps (default maps/: on a CPU, `make run`'s case-2 map;
    on a GPU, the evaluation's maps)."""
    from lmjx.bench.decisions import bench_decisions
    from lmjx.mapfile.read import load_map
    from lmjx.planner.trial import resolve_simulator

    sim_name, why = resolve_simulator(args.sim)
    print(f"lmjx bench: simulator {sim_name} ({why})", file=sys.stderr)
    folder = Path(args.maps or robot.maps_dir)
    found = {f: folder / f"{f}.h5" for f in robot.profile.presets if (folder / f"{f}.h5").exists()}
    if not found:
        build = f"lmjx build-map{_robot_flag(robot)} --failure {bench_failure(robot)}"
        return {"skipped": f"no map of the robot's presets in {folder} (build one with: {build})"}
    maps = {f: load_map(p, robot) for f, p in found.items()}
    trials = 1 if args.quick else args.decision_trials
    report = bench_decisions(robot, maps, sim_name, trials=trials, max_actions=2 if args.quick else None,
                             say=lambda line: print(f"lmjx bench: {line}", file=sys.stderr))  # fmt: skip
    report["simulator_reason"] = why
    return report


def bench_agreement(robot: Robot, args: argparse.Namespace) -> dict:
    """The planner's decisions with the tested simulator against C MuJoCo's (lmjx.evaluation.agreement)."""
    from lmjx.evaluation.agreement import decision_states, measure
    from lmjx.evaluation.evaluate import load_maps
    from lmjx.planner.trial import make_simulator, resolve_simulator
    from lmjx.sim.scenarios import resolve_task

    sim_name, why = resolve_simulator(args.sim)
    if sim_name == "cpu":
        return {"skipped": f"the simulator under test would be the reference itself ({why}); use --sim gpu or cpu-near"}
    failures = tuple(robot.profile.presets) or ("none",)
    try:
        maps = load_maps(robot, failures, Path(args.maps or robot.maps_dir))
    except LmjxError as e:
        return {"skipped": str(e)}
    scenarios = (1, 2, 3)
    seeds = 2 if args.quick else args.agreement_seeds
    decisions = decision_states(robot, maps, scenarios, seeds, 3, 8 if args.quick else 64)
    tasks = {s: resolve_task(s, robot, "hard") for s in scenarios}
    tested = {s: make_simulator(robot, tasks[s], sim_name) for s in scenarios}
    reference = {s: make_simulator(robot, tasks[s], "cpu") for s in scenarios}
    out = measure(robot, decisions, tested, reference)
    out |= {"simulator": sim_name, "maps": args.maps or robot.maps_dir, "seeds": seeds, "depth": 3}
    if sim_name == "gpu":
        # the same decisions on two GPU simulators batching them differently: how far float32
        # rounding (and the order atomics leave contacts in) carries through the scenes' contacts
        twin = {s: make_simulator(robot, tasks[s], "gpu") for s in scenarios}
        self_check = measure(robot, decisions, tested, twin)
        out["gpu_vs_gpu"] = {k: v for k, v in self_check.items() if k != "per_decision"}
    return out


def parse_sections(text: str) -> set[str]:
    got = {s.strip() for s in text.split(",") if s.strip()}
    bad = got - set(SECTIONS)
    if bad or not got:
        raise ConfigError(f"unknown bench section(s) {', '.join(sorted(bad)) or '(none)'}; use {','.join(SECTIONS)}")
    return got


def _print_ik(report: dict, iterations: int) -> None:
    print(f"  lmjx IK (PM, TCP on the task plane, {iterations} iterations):")
    for r in report["ik"]:
        print(
            f"    batch {r['batch']:>9,}: solve {_fmt_rate(r['solve_per_s'])}, solve+checks "
            f"{_fmt_rate(r['solve_check_per_s'])} "
            f"(compile {r['compile_s']:.1f} s / {r['compile_with_checks_s']:.1f} s), "
            f"accepted {r['accepted']:.2f}"
        )
    pkr = report["pytorch_kinematics"]
    if "skipped" in pkr:
        print(f"  pytorch_kinematics: skipped ({pkr['skipped']})")
    else:
        print(
            f"  pytorch_kinematics PseudoInverseIK on {pkr['device']}, batch {pkr['batch']:,}: "
            f"{_fmt_rate(pkr['solve_per_s'])} (converged {pkr['converged']:.2f})"
        )
    pb = report["pybullet"]
    if "skipped" in pb:
        print(f"  PyBullet: skipped ({pb['skipped']})")
    else:
        for run in pb["runs"]:
            print(
                f"  PyBullet calculateInverseKinematics loop on {pb['device']}, maxNumIterations "
                f"{run['max_iterations']}: {_fmt_rate(run['solve_per_s'])} (success {run['success']:.2f})"
            )


def _print_maps(report: dict) -> None:
    print("  whole Reach-Ability maps (after compilation):")
    for m in report["maps"]:
        print(
            f"    {m['failure']:>6}: {m['cells']} cells x k={m['attempts']} x {m['restarts']} restarts, "
            f"{m['seconds']:.3f} s (compile {m['compile_s']:.1f} s), PM {m['area_m2']['pm']:.3f} m^2, "
            f"NPM+PM {m['area_m2']['npm_pm']:.3f} m^2"
        )


def _print_rollouts(report: dict) -> None:
    ro = report["rollouts"]
    print(
        f"  edge rollouts ({ro['failure']}, {ro['edges_rolled_out']:,} edges of up to {ro['max_steps']} steps): "
        f"{ro['seconds']:.3f} s (compile {ro['compile_s']:.1f} s): {_fmt_rate(ro['edge_steps_per_s'])} edge-steps, "
        f"{_fmt_rate(ro['states_per_s'])} states evaluated"
    )
    rr = ro["reference"]
    print(
        f"  serial C MuJoCo rollouts, same edges ({rr['edges']}): {_fmt_rate(rr['states_per_s'])} states; "
        f"lmjx {ro['speedup_states']:,.0f}x"
    )


def _print_planner(pl: dict) -> None:
    print(
        f"  Greedy scoring, scenario {pl['scenario']} ({pl['failure']}), candidate actions of "
        f"{pl['action_seconds_mean']:.1f} s on average ({pl['distinct_edges']} distinct edges):"
    )
    for r in pl["rows"]:
        extra = ""
        if "capture_s" in r:
            extra += f" (capture {r['capture_s']:.1f} s), {r['speedup_vs_cpu']:.1f}x C MuJoCo"
        if "same_choice" in r:
            d = r["target_end_diff_m"]
            where = (f"target ends {d['median'] * 100:.2f} / {d['p90'] * 100:.2f} cm (median / p90) from C MuJoCo's"
                     if d else "nothing finite")  # fmt: skip
            bad = f", {r['non_finite']} non-finite" if r["non_finite"] else ""
            extra += f"; {where}{bad}, same choice: {r['same_choice']} (gap {r['choice_gap_m'] * 100:.1f} cm)"
        print(
            f"    {r['simulator']:>8} {r['candidates']:>5,}: {r['seconds']:.3f} s, {_fmt_rate(r['steps_per_s'])} "
            f"steps{extra}"
        )
    g = pl["decision"]
    print(
        f"    one Greedy decision ({g['simulator']}, {g['candidates']} candidates"
        + (f", its best {g['rescored']} rescored" if g.get("rescored") else "")
        + ", transits included): "
        f"{g['seconds']:.2f} s, of which simulation {g['simulation_seconds']:.2f} s"
    )
