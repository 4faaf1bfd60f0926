"""`lmjx bench`: lmjx's kernels timed against the baselines (PyBullet, pytorch_kinematics,
serial C MuJoCo); the work is in lmjx/bench/bench.py."""

from __future__ import annotations

import argparse

from lmjx.cli.common import _add_device, _add_robot, _positive_int, _positive_ints, check_suffix
from lmjx.cli.plan import _add_sim


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "bench",
        help="benchmarks against the baselines, side by side",
        description="Time lmjx's batched IK against a serial PyBullet calculateInverseKinematics loop (PyBullet's "
        "own Panda) and pytorch_kinematics' batched IK on the same device, on the same task-plane targets; and "
        "time whole Reach-Ability maps.  Compile time is reported apart from run time.",
    )
    p.add_argument("--quick", action="store_true", help="small sizes that finish in about a minute on a CPU")
    _add_robot(p)
    p.add_argument(
        "--sizes", type=_positive_ints, help="comma-separated IK batch sizes (default: by device and --quick)"
    )
    p.add_argument("--repeats", type=_positive_int, default=3, help="timed repetitions per figure; the median is kept")
    p.add_argument(
        "--sections",
        default="ik,maps,rollouts,planner",
        help="what to time, comma separated: ik (lmjx vs pytorch_kinematics vs PyBullet), maps (whole "
        "Reach-Ability maps), rollouts (edge rollouts vs serial C MuJoCo), planner (whole decisions of each ASM "
        "in every scenario, one trial at a time: each decision's latency and where it went; needs the maps in "
        "--maps), scoring (Greedy scoring, the GPU simulator vs C MuJoCo on all cores; needs a map with "
        "edges), agreement (the simulator's choices "
        "against C MuJoCo's over some 200 Greedy decisions; needs --maps with case1.h5 and case2.h5), build "
        "(the user's build-map end to end, in a fresh process: seconds per stage, wall / kernel time, the "
        "preflight's error) (default: ik,maps,rollouts,planner)",
    )
    p.add_argument(
        "--edges",
        type=_positive_ints,
        help="build: sampled edges per timed build, comma separated (default 100000,1000000 on a GPU, 10000 on a CPU)",
    )
    p.add_argument("--failure", help="build: the failure to build (default case2 where the robot has it)")
    p.add_argument(
        "--maps", help="planner, agreement: folder of the robot's preset maps (default maps, or maps/<robot>)"
    )
    p.add_argument(
        "--decision-trials", type=_positive_int, default=3, metavar="N",
        help="planner: trials per failure, scenario and ASM (default 3; 1 with --quick)",
    )
    p.add_argument(
        "--agreement-seeds", type=_positive_int, default=12, help="agreement: trials per failure and scenario (12)"
    )
    p.add_argument(
        "--planner-map", help="map for the scoring section (default maps/case2.h5, or maps/<robot>/case2.h5)"
    )
    p.add_argument(
        "--candidates",
        type=_positive_ints,
        help="scoring section: candidate counts to score, comma separated (default 256,1024,4096 with a GPU "
        "simulator, 256 without; 8 with --quick)",
    )
    _add_sim(p)
    p.add_argument("--out", help="write the results as JSON to this file (.json)")
    p.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    _add_device(p)
    p.set_defaults(run=cmd_bench)
    return p


def cmd_bench(args: argparse.Namespace) -> int:
    if args.out:
        check_suffix(args.out, "--out", (".json",), "the results are written as JSON")
    from lmjx.bench.bench import run_bench

    return run_bench(args)
