"""The GPU simulator's agreement test (tests/test_simulate_gpu.py, 200+ Greedy decisions
against C MuJoCo) outside pytest, on any Warp device: its out-of-sample decisions (maps of
seed 4049, trial seeds 700-711, the three scenarios, depth 3, 64 candidates) measured by
`lmjx.evaluation.agreement.measure` in the evaluation's configuration (servo model "robot",
Greedy's rescoring), the report written as JSON and its pass/fail against the thresholds set
with those seeds, before the test's first run.  On a machine without a GPU
(`--device cpu`, Warp's CPU device: float32 as on the GPU, the same picks where checked)
it is a stand-in for the GPU's run, not the test itself.

    python benchmarks/agreement_run.py MAPS_DIR --out agree.json [--device cpu] [--seeds N]

MAPS_DIR: case1.h5 and case2.h5 built with `lmjx build-map --failure caseN --edges 100000
--seed 4049`.  The decisions need no simulator and take most of the time (about 16 s each on
one core): a machine without a GPU may build them for one with, or a GPU machine in a run of
its own (the test reads them from LMJX_TEST_DECISIONS),

    python benchmarks/agreement_run.py MAPS_DIR --save-decisions decisions.pkl.gz   # no GPU needed
    python benchmarks/agreement_run.py MAPS_DIR --decisions decisions.pkl.gz --out agree.json  # on the GPU

(the maps are read either way: Greedy's score weighs the path by their push counts)

(the file: a gzip'd pickle of `lmjx.evaluation.agreement.Decision`s, with the maps' seed and sizes;
pickle runs code when read: load only files you made).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from lmjx.errors import LmjxError
from lmjx.evaluation.agreement import (
    FIRST_SEED,
    MAP_SEED,
    MIN_DECISIONS,
    OUT_OF_SAMPLE_SEEDS,
    SERVO,
    load_decisions,
    out_of_sample,
    out_of_sample_decisions,
    passes,
    save_decisions,
)
from lmjx.evaluation.evaluate import load_maps
from lmjx.model.robot import load_robot
from lmjx.planner.trial import make_simulator
from lmjx.runtime.fileio import write_text_atomic
from lmjx.sim.scenarios import resolve_task


def setup(prog: str, failures: tuple[str, ...], maps_dir: Path | None, warp: bool = True) -> tuple:
    """The Panda, its maps for `failures` (none without `maps_dir`) and MuJoCo Warp's config
    class (`GpuSimConfig`; None without `warp`), or a one-line exit naming `prog` (no
    warp-lang, a missing or foreign map)."""
    GpuSimConfig = None
    if warp:
        try:
            import warp as _warp  # noqa: F401  (MuJoCo Warp's runtime; lmjx.sim.gpu imports it when it runs)

            from lmjx.sim.gpu import GpuSimConfig
        except ImportError as e:
            sys.exit(f"{prog}: {e} (the GPU extra: pip install -e '.[gpu]', or warp-lang alone for --device cpu)")
    robot = load_robot("panda")
    if maps_dir is None:
        return robot, {}, GpuSimConfig
    try:
        maps = load_maps(robot, failures, maps_dir)
    except LmjxError as e:
        sys.exit(f"{prog}: {e}")
    return robot, maps, GpuSimConfig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("maps", type=Path, help="folder of case1.h5 and case2.h5 (seed 4049)")
    ap.add_argument("--out", type=Path, help="the report (JSON)")
    ap.add_argument("--device", default=None, help="Warp device: cpu, or cuda:0 (default: the first CUDA device)")
    ap.add_argument("--seeds", type=int, default=OUT_OF_SAMPLE_SEEDS, help="trial seeds from 700 (default: the test's)")
    ap.add_argument("--save-decisions", type=Path, help="build the decisions only (no simulator) and write them here")
    ap.add_argument("--decisions", type=Path, help="measure decisions built before (--save-decisions)")
    args = ap.parse_args()
    if not 1 <= args.seeds <= OUT_OF_SAMPLE_SEEDS:
        sys.exit(f"agreement_run: --seeds must lie in 1-{OUT_OF_SAMPLE_SEEDS} (the test's seeds from {FIRST_SEED})")
    if args.save_decisions is None and args.out is None:
        sys.exit("agreement_run: --out is needed (or --save-decisions, to build the decisions only)")
    if args.save_decisions is not None and args.decisions is not None:
        sys.exit("agreement_run: --save-decisions builds decisions from the maps, not from --decisions")
    robot, maps, GpuSimConfig = setup("agreement_run", ("case1", "case2"), args.maps, warp=args.save_decisions is None)
    for f, m in maps.items():
        if m.edges.config.seed != MAP_SEED or m.reach.config.seed != MAP_SEED:
            sys.exit(f"agreement_run: {f}: not a map of seed {MAP_SEED} (the test's out-of-sample maps)")
    built = None
    if args.decisions is not None:
        try:
            blob = load_decisions(args.decisions)
        except LmjxError as e:
            sys.exit(f"agreement_run: {e}")
        args.seeds = blob["seeds"]
        built = (blob["decisions"], blob["seconds"], blob["workers"])
        print(f"{len(built[0])} decisions of maps {blob['maps']} ({built[1]:.0f} s, {built[2]} workers)")
    elif args.save_decisions is not None:
        made = out_of_sample_decisions(robot, maps, args.seeds)
        save_decisions(args.save_decisions, made, maps, args.seeds)
        print(f"{len(made[0])} decisions in {made[1]:.0f} s ({made[2]} workers): {args.save_decisions}")
        return
    cfg = None
    if args.device:  # on Warp's CPU device padding costs its full time: finer batch sizes
        fine = (64, 256, 512, 1024, 2048, 4096) if args.device == "cpu" else GpuSimConfig().buckets
        cfg = GpuSimConfig(device=args.device, buckets=fine)
    report = out_of_sample(
        robot,
        maps,
        {
            s: make_simulator(robot, resolve_task(s, robot, "hard"), "gpu", gpu_config=cfg, servo=SERVO)
            for s in (1, 2, 3)
        },
        {s: make_simulator(robot, resolve_task(s, robot, "hard"), "cpu", servo=SERVO) for s in (1, 2, 3)},
        args.seeds,
        built=built,
    )
    report |= {"device": args.device or "cuda", "passed": passes(report)}
    write_text_atomic(args.out, json.dumps(report, indent=1) + "\n")
    verdict = "passed" if report["passed"] else "FAILED"
    if report["decisions"] < MIN_DECISIONS:
        verdict = f"a sample of {report['decisions']} decisions, no verdict (the test asks for {MIN_DECISIONS})"
    print(
        f"{report['decisions']} decisions, {report['candidates']} candidates: "
        f"same action {100 * report['same_choice']:.1f} %, "
        f"same or within 1 cm {100 * report['same_or_within_1cm']:.1f} %, target ends median "
        f"{report['target_end_diff_m']['median'] * 1e6:.2f} um apart, non-finite {report['non_finite']}: "
        f"{verdict} (decisions {report['seconds']['decisions']:.0f} s, tested {report['seconds']['tested']:.0f} s, "
        f"reference {report['seconds']['reference']:.0f} s)"
    )


if __name__ == "__main__":
    main()
