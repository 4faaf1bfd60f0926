"""`lmjx plan`: one manipulation task with simulation in the loop (paper Algorithm 3), and
the planner's options that `lmjx evaluate` shares."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from lmjx.cli.common import _add_device, _add_robot, _emit, _load_robot, _nonnegative_int, _positive_int
from lmjx.sim.scenarios import PAPER_BUDGET, Scenario

if TYPE_CHECKING:
    from lmjx.types import PlannerConfig


def _add_sim(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--sim",
        choices=("auto", "cpu", "cpu-near", "gpu"),
        default="auto",
        help="the planner's simulator: gpu (MuJoCo Warp on a CUDA GPU, the whole scene), cpu (C MuJoCo on all "
        "host cores, the whole scene), cpu-near (C MuJoCo, only the target and its 3 nearest objects) or auto "
        "(default: gpu where a CUDA GPU and warp-lang are present, else cpu); the choice is printed on stderr "
        "and given in --json",
    )


def _add_planner_options(p: argparse.ArgumentParser) -> None:
    """The planner's options, shared by plan and evaluate."""
    p.add_argument(
        "--tasks",
        choices=("paper", "hard"),
        default="paper",
        help="the task set: paper (default; goal regions, distances and budget calibrated to the paper's reported "
        "outcomes, docs/EVALUATION.md) or hard (goals 22-28 cm away: tasks where choosing by simulation matters)",
    )
    p.add_argument(
        "--max-actions",
        type=_positive_int,
        help=f"action budget per task (default: the task set's: paper {PAPER_BUDGET}, hard {Scenario.budget})",
    )
    p.add_argument(
        "--candidates",
        type=_positive_int,
        help="greedy: actions simulated per decision (default 1024 with --sim gpu, 32 on the CPU)",
    )
    p.add_argument(
        "--asm-settings",
        choices=("lmjx", "paper"),
        default="lmjx",
        help="lmjx (default): with lmjx's refinements (edges that failed are not offered again while the "
        "target stays put, the path length around obstacles as the score, Lazy capped at 32 tries and "
        "taking its best when none helps); paper: the ASMs as the paper states them (none of these; Greedy "
        "simulates a quarter of the edges over the target)",
    )
    p.add_argument(
        "--when-stuck",
        choices=("best", "options"),
        default="best",
        help="greedy, when no candidate is predicted to bring the target 5 mm closer: best (default, the paper's "
        "Greedy) takes the best predicted all the same; options takes the candidate whose predicted state leaves "
        "the most edges to offer (starts clear of the scene, acting on the target), the best predicted among "
        "those with at least 80%% of the most (measured worse on the hard set's case-2 tunnel: docs/EVALUATION.md)",
    )
    p.add_argument(
        "--late-start",
        action="store_true",
        help="where the edges with clear starts give fewer candidates than wanted, offer edges whose start lies "
        "within 2 cm of a fixed obstacle (the tunnel's wall or roof) from their first state clear of the scene, "
        "where the rest still acts on the target (default: such an edge is not offered; a lever for the tunnel, "
        "docs/EVALUATION.md)",
    )
    p.add_argument(
        "--push-weight",
        type=_nonnegative_float,
        default=None,
        metavar="W",
        help="greedy and lazy score a candidate by the cost of the target's way to the goal, each metre weighted "
        "by 1 + W ln(median / n), n the map's edges that push toward the goal there (the counts take a few "
        "minutes per map and scenario on a CPU, then are kept in lmjx's cache folder); default 1 (0 with "
        "--asm-settings paper, which scores by the straight distance and takes no weight); 0: the path length "
        "around the fixed obstacles alone (docs/EVALUATION.md)",
    )
    p.add_argument(
        "--rescore-top",
        type=_nonnegative_int,
        default=None,
        metavar="N",
        help="greedy simulates its N best candidates again, each from --rescore-draws - 1 more starts with every "
        "object's observed pose redrawn by the camera's noise (2 mm, 1.5 deg), and takes the one whose mean score "
        "over all its starts is lowest (a push whose outcome hangs on millimetres no longer wins on one lucky "
        "rollout; N x (K - 1) more rollouts a decision); default 8 (0 with --asm-settings paper); 0: off "
        "(why: docs/EVALUATION.md, its method changes)",
    )
    p.add_argument(
        "--rescore-draws",
        type=_nonnegative_int,
        default=8,
        metavar="K",
        help="starts per rescored candidate, the observed one included (default 8; at least 2)",
    )
    p.add_argument(
        "--servo",
        choices=("playback", "robot"),
        default="robot",
        help="how the planner's simulator tracks the arm's joint targets: robot (default: the robot's own joint "
        "servo gains and torque limits, as its controller tracks them: simulated pushes lag and overshoot as the "
        "arm's do) or playback (stiff servos with unlimited torque, the trajectory played back nearly exactly; "
        "why the default: docs/EVALUATION.md, its method changes)",
    )
    _add_sim(p)


def _nonnegative_float(text: str) -> float:
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value >= 0.0):
        raise argparse.ArgumentTypeError(f"must be a number at least 0, got {text}")
    return value


def _resolve_sim(args: argparse.Namespace) -> tuple[str, str]:
    """The planner's simulator for --sim, announced on stderr."""
    from lmjx.evaluation.trial import resolve_simulator

    name, why = resolve_simulator(args.sim)
    print(f"lmjx {args.command}: simulator {name} ({why})", file=sys.stderr)
    return name, why


def _planner_config(args: argparse.Namespace, asm: str, sim: str) -> PlannerConfig:
    from lmjx.api import planner_config

    return planner_config(
        asm, sim, args.max_actions, args.candidates, args.asm_settings, args.when_stuck, args.late_start,
        args.push_weight, args.rescore_top, args.rescore_draws, args.servo,
    )  # fmt: skip


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "plan",
        help="one manipulation task with simulation in the loop (paper Algorithm 3)",
        description="Push the target cube of a scenario into its goal region using the edges of a map, choosing "
        "each action with an action selection mechanism (random, lazy or greedy) and executing it in a simulated "
        "'real' world whose physics differ from the planner's.  The times printed: planning is wall-clock time "
        "here, less any compiling of kernels on first use (printed apart); robot time is the simulated time the "
        "arm spends executing the actions.",
    )
    p.add_argument("--map", required=True, help="a map file from lmjx build-map")
    p.add_argument("--scenario", required=True, type=int, choices=(1, 2, 3), help="1: clutter, 2: tunnel, 3: 11 boxes")
    p.add_argument("--asm", required=True, choices=("random", "lazy", "greedy"), help="action selection mechanism")
    p.add_argument("--failure", help="refuse the map unless it was built for this failure")
    _add_robot(p, from_map=True)
    p.add_argument("--seed", type=int, default=0, help="trial seed: layout, 'real' world, planner choices (default 0)")
    _add_planner_options(p)
    p.add_argument("--render", help="write a rendering of the trial: .png (frame strip), .gif or .mp4")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    _add_device(p)
    p.set_defaults(run=cmd_plan)
    return p


def cmd_plan(args: argparse.Namespace) -> int:
    from lmjx.api import plan_task

    r = plan_task(
        args.map, args.scenario, asm=args.asm, seed=args.seed, tasks=args.tasks, max_actions=args.max_actions,
        candidates=args.candidates, asm_settings=args.asm_settings, when_stuck=args.when_stuck,
        late_start=args.late_start, push_weight=args.push_weight, rescore_top=args.rescore_top,
        rescore_draws=args.rescore_draws, servo=args.servo, sim=args.sim,
        robot=_load_robot(args) if args.robot else None,  # None: the robot the map names
        failure=args.failure, render=args.render, say=lambda line: print(f"lmjx plan: {line}", file=sys.stderr),
    )  # fmt: skip
    res, summary = r.trial, r.summary()
    lines = [
        f"failure {r.failure}, scenario {args.scenario} ({args.tasks} tasks), {args.asm}, seed {args.seed}: "
        f"{'success' if res.success else 'failure'} ({res.reason}) after {res.actions} actions",
        f"  planning {res.planning_s:.1f} s (wall clock), robot time {res.execution_s:.1f} s (simulated execution), "
        f"target {res.final_distance * 100:.1f} cm from the goal's centre",
    ]
    if res.compile_s >= 0.05:
        lines.append(f"  compiling on first use: {res.compile_s:.1f} s (not in the planning time)")
    if r.simulator_description is not None:
        lines.append(f"  simulator: {r.simulator_description}")
    if args.render:
        lines.append(f"  rendering written to {args.render}")
    _emit(args, summary, lines)
    return 0
