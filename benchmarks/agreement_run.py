"""The GPU simulator's agreement test (tests/test_simulate_gpu.py, 200+ Greedy decisions
against C MuJoCo) outside pytest, on any Warp device: its out-of-sample decisions (maps of
seed 2026, trial seeds 500-511, the three scenarios, depth 3, 64 candidates) measured by
`lmjx.agreement.measure`, the report written as JSON and its pass/fail against the
thresholds set before the test's first out-of-sample run.  On a machine without a GPU
(`--device cpu`, Warp's CPU device: float32 as on the GPU, the same picks where checked)
it is a stand-in for the GPU's run, not the test itself.

    python benchmarks/agreement_run.py MAPS_DIR --out agree.json [--device cpu] [--seeds N]

MAPS_DIR: case1.h5 and case2.h5 built with `lmjx build-map --failure caseN --edges 100000
--seed 2026`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from lmjx.agreement import decision_states, measure
from lmjx.errors import LmjxError
from lmjx.evaluate import load_maps
from lmjx.fileio import write_text_atomic
from lmjx.robot import load_robot
from lmjx.scenarios import scenario
from lmjx.scene import build_scene
from lmjx.trial import make_simulator

MAP_SEED, FIRST_SEED = 2026, 500  # tests/test_simulate_gpu.py's, chosen before its first out-of-sample run
PASS = {"decisions": 200, "same_or_within_1cm": 0.95, "median_end_diff_m": 1e-4}


def setup(prog: str, failures: tuple[str, ...], maps_dir: Path) -> tuple:
    """The Panda, its maps for `failures` and MuJoCo Warp's simulator (its config class and
    its class), or a one-line exit naming `prog` (no warp-lang, a missing or foreign map)."""
    try:
        import warp  # noqa: F401  (MuJoCo Warp's runtime; lmjx.simulate_gpu imports it when it runs)

        from lmjx.simulate_gpu import GpuSimConfig, GpuSimulator
    except ImportError as e:
        sys.exit(f"{prog}: {e} (the GPU extra: pip install -e '.[gpu]', or warp-lang alone for --device cpu)")
    robot = load_robot("panda")
    try:
        maps = load_maps(robot, failures, maps_dir)
    except LmjxError as e:
        sys.exit(f"{prog}: {e}")
    return robot, maps, GpuSimConfig, GpuSimulator


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("maps", type=Path, help="folder of case1.h5 and case2.h5 (seed 2026)")
    ap.add_argument("--out", type=Path, required=True, help="the report (JSON)")
    ap.add_argument("--device", default=None, help="Warp device: cpu, or cuda:0 (default: the first CUDA device)")
    ap.add_argument("--seeds", type=int, default=12, help="trial seeds from 500 (default 12: the test)")
    args = ap.parse_args()
    if not 1 <= args.seeds <= 12:
        sys.exit("agreement_run: --seeds must lie in 1-12 (the test's seeds 500-511)")
    robot, maps, GpuSimConfig, GpuSimulator = setup("agreement_run", ("case1", "case2"), args.maps)
    for f, m in maps.items():
        if m.edges.config.seed != MAP_SEED or m.reach.config.seed != MAP_SEED:
            sys.exit(f"agreement_run: {f}: not a map of seed {MAP_SEED} (the test's out-of-sample maps)")
    t0 = time.perf_counter()
    decisions = decision_states(robot, maps, (1, 2, 3), args.seeds, 3, 64, first_seed=FIRST_SEED)
    print(f"{len(decisions)} decisions in {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    cfg = None
    if args.device:  # on Warp's CPU device padding costs its full time: finer batch sizes
        fine = (64, 256, 512, 1024, 2048, 4096) if args.device == "cpu" else GpuSimConfig().buckets
        cfg = GpuSimConfig(device=args.device, buckets=fine)
    tested = {
        s: GpuSimulator(build_scene(robot, scenario(s, robot.profile.task_scale, "hard"), fuse_static=True), config=cfg)
        for s in (1, 2, 3)
    }
    reference = {s: make_simulator(robot, s, "cpu", "hard") for s in (1, 2, 3)}
    report = measure(robot, decisions, tested, reference)
    report |= {"map_seed": MAP_SEED, "first_seed": FIRST_SEED, "seeds": args.seeds, "device": args.device or "cuda"}
    report["passed"] = bool(
        report["decisions"] >= PASS["decisions"]
        and report["non_finite"] == 0
        and report["target_end_diff_m"]["median"] <= PASS["median_end_diff_m"]
        and report["same_or_within_1cm"] >= PASS["same_or_within_1cm"]
    )
    write_text_atomic(args.out, json.dumps(report, indent=1) + "\n")
    verdict = "passed" if report["passed"] else "FAILED"
    if report["decisions"] < PASS["decisions"]:
        verdict = f"a sample of {report['decisions']} decisions, no verdict (the test asks for {PASS['decisions']})"
    print(
        f"{report['decisions']} decisions, {report['candidates']} candidates: "
        f"same action {100 * report['same_choice']:.1f} %, "
        f"same or within 1 cm {100 * report['same_or_within_1cm']:.1f} %, target ends median "
        f"{report['target_end_diff_m']['median'] * 1e6:.2f} um apart, non-finite {report['non_finite']}: "
        f"{verdict} (tested {report['seconds']['tested']:.0f} s, "
        f"reference {report['seconds']['reference']:.0f} s)"
    )


if __name__ == "__main__":
    main()
