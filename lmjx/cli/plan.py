"""`lmjx plan`: one manipulation task with simulation in the loop (paper Algorithm 3); and the
planner's options `lmjx evaluate` shares: the everyday ones, and the planner's levers, given as
keys of its configuration (`--planner-config FILE`, `--set KEY=VALUE`, `--help-levers`:
`lmjx.planner.levers`).  The options that each set one lever (`MOVED`) are accepted, hidden
from --help, and say in one line on stderr which key they set."""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any

from lmjx.cli.common import (
    EXIT_TASK_FAILED,
    SEED_RANGE,
    _add_device,
    _add_robot,
    _emit,
    _load_robot,
    _nonnegative_int,
    _positive_int,
    _seed,
)


def _nonnegative_float(text: str) -> float:
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value >= 0.0):
        raise argparse.ArgumentTypeError(f"must be a number at least 0, got {text}")
    return value


# Options that each set one lever, hidden from --help (the key says the same): (option, key, how argparse reads it)
MOVED: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("--asm-settings", "asm_settings", {"choices": ("lmjx", "paper")}),
    ("--when-stuck", "when_stuck", {"choices": ("best", "options")}),
    ("--late-start", "late_start", {"action": "store_const", "const": True}),
    ("--push-weight", "push_weight", {"type": _nonnegative_float}),
    ("--rescore-top", "rescore_top", {"type": _nonnegative_int}),
    ("--rescore-draws", "rescore_draws", {"type": _nonnegative_int}),
    ("--servo", "servo", {"choices": ("playback", "robot")}),
)
LEVERS_EPILOG = (
    "Research levers (the ASMs' settings, rescoring, the push weight, the servo model, ...): --set KEY=VALUE or "
    "--planner-config FILE; --help-levers lists them (docs/PLANNER.md)."
)
# How a trial can end: each of `lmjx.planner.records.ENDS`, what the summary prints in brackets after
# "success" or "failure" (--json: `end`; `stopped`: what stopped the planner), and what it means
END_MEANINGS: dict[str, str] = {
    "goal": "the target ended in the goal region (a success), whatever stopped the planner; the planner stops "
    "once it observes the target goal_margin (1 cm) inside the region",
    "budget": "the action budget (the task's, or --max-actions) was spent and the target is not in the goal",
    "planning limit": "before a decision, the planner had simulated max_sim_steps control steps (a count, the same "
    "on every host, not seconds)",
    "no edge over the target": "no edge of the map, and no turned copy of one, passes over the target where it lies",
    "no feasible transit": "edges over the target were tested and none could be offered; some had a clear start "
    "and a usable edge but no collision-free transit to that start",
    "no feasible action": "edges over the target were tested and none could be offered, and none lacked only a "
    "transit: their starts were blocked (in the table, in the arm, within an object's margin) or the edges "
    "were unusable there (cut short by a fixed obstacle, or not reaching into the target)",
    "no edge moves the target": "lazy simulated its tries and none brought the target closer, and it takes no "
    "fallback (lazy_fallback false, as with --set asm_settings=paper)",
    "target off the table": "an executed action pushed the target off the table; the planner stops",
}
ENDS_EPILOG = "How a trial ends (goal, budget, planning limit, no feasible transit, ...): --help-ends."


def ends_text() -> str:
    """What --help-ends prints: every end a trial can report, with its meaning."""
    import textwrap

    from lmjx.planner.records import ENDS

    head = (
        "How a trial ends: lmjx plan prints it in brackets after success or failure; --json gives it as 'end', and "
        "what stopped the planner as 'stopped' (the two differ only where the target ended in the goal)."
    )
    lines = [textwrap.fill(head, 79), ""]
    lines += [textwrap.fill(f"{end}: {END_MEANINGS[end]}", 79, subsequent_indent="    ") for end in ENDS]
    return "\n".join(lines)


class _HelpLevers(argparse.Action):
    """--help-levers: print every lever with its default and meaning, and exit."""

    def __init__(self, option_strings: list[str], dest: str, help: str | None = None) -> None:
        super().__init__(option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, nargs=0, help=help)

    def text(self) -> str:
        from lmjx.planner.levers import levers_text

        return levers_text()

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:  # fmt: skip
        import os

        try:
            print(self.text(), flush=True)
        except BrokenPipeError:  # (`lmjx plan --help-levers | head`): not an error
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        parser.exit()


class _HelpEnds(_HelpLevers):
    """--help-ends: print every end a trial can report with its meaning, and exit."""

    def text(self) -> str:
        return ends_text()


def _add_sim(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--sim",
        choices=("auto", "cpu", "cpu-near", "gpu"),
        default="auto",
        help="the planner's simulator: gpu (MuJoCo Warp), cpu (C MuJoCo, all cores), cpu-near (C MuJoCo, the "
        "target and its 3 nearest objects) or auto (default: gpu where it can run)",
    )


def _add_planner_options(p: argparse.ArgumentParser) -> None:
    """The planner's options, shared by plan and evaluate."""
    p.add_argument(
        "--tasks",
        choices=("paper", "hard"),
        help="the shipped scenarios' task set: paper (default; calibrated to the paper's outcomes) or hard "
        "(goals 22-28 cm away)",
    )
    p.add_argument(
        "--max-actions",
        type=_positive_int,
        metavar="N",
        help="action budget per task (default: the task's)",
    )
    p.add_argument(
        "--candidates",
        type=_positive_int,
        metavar="N",
        help="greedy: actions simulated per decision (default 1024 with --sim gpu, 32 on the CPU)",
    )
    _add_sim(p)
    p.add_argument("--planner-config", metavar="FILE", help="the levers from a TOML file (KEY = VALUE)")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="set one lever, e.g. --set asm_settings=paper (repeatable; wins over --planner-config)",
    )
    p.add_argument("--help-levers", action=_HelpLevers, help="list the levers with their defaults and meanings; exit")
    for option, key, how in MOVED:
        p.add_argument(option, dest=key, default=None, help=argparse.SUPPRESS, **how)


def _text(value: Any) -> str:
    """A lever's value as --set takes it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return f"{value:g}" if isinstance(value, float) else str(value)


def planner_levers(args: argparse.Namespace) -> dict[str, Any]:
    """The levers the command line gives: --planner-config's, then --set's, then the moved
    options' and --max-actions and --candidates (each of these wins over what came before)."""
    from lmjx.planner.levers import parse_sets, read_levers

    levers = read_levers(args.planner_config) if args.planner_config else {}
    levers |= parse_sets(args.set)
    levers |= {key: getattr(args, key) for _, key, _ in MOVED if getattr(args, key) is not None}
    if args.max_actions is not None:
        levers["max_actions"] = args.max_actions
    if args.candidates is not None:
        levers["greedy_candidates"] = args.candidates
    return levers


def moved_notes(args: argparse.Namespace) -> list[str]:
    """One line per option of one lever given, saying how its key is set."""
    return [
        f"lmjx {args.command}: note: {option} moved to --set {key}={_text(getattr(args, key))}"
        for option, key, _ in MOVED
        if getattr(args, key) is not None
    ]


def task_set(args: argparse.Namespace, scenes: bool) -> str:
    """The task set --tasks names (paper where not given); refused beside scene files, which
    state their own."""
    from lmjx.errors import ConfigError

    if scenes and args.tasks is not None:
        raise ConfigError("--tasks chooses among the shipped scenarios; a scene file states its task set "
                          "(task_set): leave out --tasks")  # fmt: skip
    return args.tasks or "paper"


def _resolve_sim(args: argparse.Namespace) -> tuple[str, str]:
    """The planner's simulator for --sim, announced on stderr."""
    from lmjx.planner.trial import resolve_simulator

    name, why = resolve_simulator(args.sim)
    print(f"lmjx {args.command}: simulator {name} ({why})", file=sys.stderr)
    return name, why


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "plan",
        help="one manipulation task with simulation in the loop (paper Algorithm 3)",
        description="Push the target cube of a scenario (--scenario N: the paper's; --scene FILE: a scene file, "
        "docs/SCENES.md) into its goal region with the edges of a map, choosing "
        "each action by an action selection mechanism and executing it in a simulated 'real' world whose physics "
        "differ from the planner's.  Planning time is wall clock less compiling on first use (printed apart); "
        "robot time is the simulated time the arm spends executing the actions.  The planning limit counts "
        "simulated control steps, not seconds: the trial stops before a decision once its planner has simulated "
        "max_sim_steps of them (--set max_sim_steps=N; the same count on every host), a failure unless the "
        "target is in the goal.",
        epilog=f"{LEVERS_EPILOG}  {ENDS_EPILOG}",
    )
    p.add_argument("--map", required=True, metavar="FILE", help="a map file from lmjx build-map")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--scenario", type=int, choices=(1, 2, 3), help="1: clutter, 2: tunnel, 3: 11 boxes")
    which.add_argument("--scene", metavar="FILE", help="your own scene file (TOML, docs/SCENES.md)")
    p.add_argument("--asm", required=True, choices=("random", "lazy", "greedy"), help="action selection mechanism")
    p.add_argument("--failure", metavar="SPEC", help="refuse the map unless it was built for this failure")
    _add_robot(p, from_map=True)
    p.add_argument(
        "--seed",
        type=_seed,
        default=0,
        help=f"trial seed, {SEED_RANGE}: layout, 'real' world, planner choices (default 0)",
    )
    _add_planner_options(p)
    p.add_argument("--help-ends", action=_HelpEnds, help="list how a trial can end, each end's meaning; exit")
    p.add_argument("--render", metavar="FILE", help="write the trial as .png (frames), .gif or .mp4")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.add_argument(
        "--strict", action="store_true", help=f"exit with status {EXIT_TASK_FAILED} if the target ends outside the goal"
    )
    _add_device(p)
    p.set_defaults(run=cmd_plan)
    return p


def _count(n: int, noun: str) -> str:
    """"1 action", "3 actions"."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def goal_size(args: argparse.Namespace, tasks: str) -> str:
    """The goal region's size along x and y, as the summary gives it ("16 x 16 cm"): the task's
    goal_half, which placing the task for a robot leaves as it is."""
    from lmjx.sim.scenarios import scenario
    from lmjx.sim.scenefile import read_scene

    sc = read_scene(args.scene).scenario if args.scene is not None else scenario(args.scenario, tasks=tasks)
    sx, sy = (round(2 * half * 100, 1) for half in sc.goal_half)
    return f"{sx:g} x {sy:g} cm"


def cmd_plan(args: argparse.Namespace) -> int:
    from lmjx.mapfile.openable import check_map_path
    from lmjx.planner.levers import check_levers

    levers = planner_levers(args)
    check_levers(levers)  # (a mistake in the levers first, as plan_task finds it)
    check_map_path(args.map)  # (a path that is no map: said before the heavy imports)
    from lmjx.api import plan_task

    notes = moved_notes(args)  # said once the arguments are checked (a refusal stays one line)

    def say(line: str | None = None) -> None:
        while notes:
            print(notes.pop(0), file=sys.stderr)
        if line is not None:
            print(f"lmjx plan: {line}", file=sys.stderr)

    tasks = task_set(args, args.scene is not None)
    quiet = os.environ.get("LMJX_PROGRESS", "").strip() == "0"

    def progress(k: int, budget: int, step) -> None:  # a line per executed action
        say(f"action {k}/{budget}: target {step.distance_after * 100:.1f} cm from the goal's centre, "
            f"decided in {step.latency_s:.1f} s")  # fmt: skip

    r = plan_task(
        args.map, args.scene if args.scene is not None else args.scenario, asm=args.asm, seed=args.seed, tasks=tasks,
        sim=args.sim,
        robot=_load_robot(args) if args.robot else None,  # None: the robot the map names
        failure=args.failure, render=args.render, say=say, planner=levers,
        on_action=None if quiet else progress,
    )  # fmt: skip
    say()
    res, summary = r.trial, r.summary()
    lines = [
        f"failure {r.failure}, {r.task} ({r.tasks} tasks), {args.asm}, seed {args.seed}: "
        f"{'success' if res.success else 'failure'} ({res.reason}) after {_count(res.actions, 'action')}",
        f"  planning {res.planning_s:.1f} s (wall clock), robot time {res.execution_s:.1f} s (simulated execution), "
        f"target {res.final_distance * 100:.1f} cm from the centre of the {goal_size(args, tasks)} goal",
    ]
    if res.compile_s >= 0.05:
        lines.append(f"  compiling on first use: {res.compile_s:.1f} s (not in the planning time)")
    if r.simulator_description is not None:
        lines.append(f"  simulator: {r.simulator_description}")
    if args.render:
        lines.append(f"  rendering written to {args.render}")
    _emit(args, summary, lines)
    return EXIT_TASK_FAILED if args.strict and not res.success else 0
