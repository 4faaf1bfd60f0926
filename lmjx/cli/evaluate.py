"""`lmjx evaluate`: trials over failures x scenarios x ASMs with a report and figures;
results.json is written after every trial, so the same command resumes an interrupted run."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from lmjx.cli.common import _add_device, _add_robot, _emit, _leave_interrupted, _load_robot, _positive_int, _seed
from lmjx.cli.plan import LEVERS_EPILOG, _add_planner_options, moved_notes, planner_levers, task_set

# Trials per cell: a trial's seed holds its number below 1000 (`evaluation.evaluate.trial_seed`),
# so that no two trials share a seed.
MAX_TRIALS = 1000


def _trials(text: str) -> int:
    v = _positive_int(text)
    if v > MAX_TRIALS:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_TRIALS}, got {text}")
    return v


def _base_seed(text: str) -> int:
    """The trials' base seed: every trial's seed (`trial_seed`) must be a seed `lmjx plan --seed` takes."""
    from lmjx.checks import SEED_MAX
    from lmjx.evaluation.evaluate import trial_seed

    v = _seed(text)
    most = (SEED_MAX - trial_seed(0, 3, MAX_TRIALS - 1)) // trial_seed(1, 0, 0)
    if v > most:
        raise argparse.ArgumentTypeError(f"must be at most {most} (the trials' seeds stay below 2**32), got {text}")
    return v


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "evaluate",
        help="trials over failures x scenarios x ASMs, with a report",
        description="Run the paper's evaluation: --trials tasks for each failure, scenario and ASM.  results.json "
        "is written after every trial, with its provenance (a rerun continues; an --out of other conditions is "
        "refused); then report.md (95 % intervals), bubble.png, actions.png.",
        epilog=LEVERS_EPILOG,
    )
    p.add_argument("--failures", metavar="LIST", help="comma separated (default: the robot's presets)")
    _add_robot(p)
    which = p.add_mutually_exclusive_group()
    which.add_argument("--scenarios", metavar="LIST", help="the paper's scenarios, comma separated (default 1,2,3)")
    which.add_argument(
        "--scenes",
        nargs="+",
        metavar="FILE",
        help="scene files instead (TOML: docs/SCENES.md)",
    )
    p.add_argument(
        "--asms", default="random,lazy,greedy", metavar="LIST", help="comma separated (default random,lazy,greedy)"
    )
    p.add_argument(
        "--trials", type=_trials, default=15, metavar="N", help=f"trials per cell, 1 to {MAX_TRIALS} (default 15)"
    )
    p.add_argument("--maps", metavar="DIR", help="folder of <failure>.h5 (default maps/ or maps/<robot>)")
    p.add_argument("--seed", type=_base_seed, default=0, help="base seed of the trials, 0 to 42949 (default 0)")
    p.add_argument(
        "--part",
        metavar="K/N",
        default="1/1",
        help="trials K, K+N, ... of each cell, into its own --out (merged by benchmarks/eval_acceptance.py)",
    )
    _add_planner_options(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument(
        "--allow-mixed",
        action="store_true",
        help="add to an --out of other conditions; report.md says so",
    )
    p.add_argument(
        "--registered",
        metavar="FILE",
        help="refuse all but the run FILE registers (REPLICATE.md)",
    )
    p.add_argument(
        "--processes",
        type=_processes,
        metavar="N",
        help="trials in N processes (default: GPUs x cores/4 with --sim gpu, else 1)",
    )
    p.add_argument("--json", action="store_true", help="print the summary table as JSON on stdout")
    _add_device(p)
    p.set_defaults(run=cmd_evaluate)
    return p


def _processes(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if not 1 <= n <= 64:
        raise argparse.ArgumentTypeError(f"'{text}': give a whole number of processes from 1 to 64")
    return n


def _split(text: str, cast: Callable = str) -> tuple:
    from lmjx.errors import ConfigError

    try:
        return tuple(cast(x.strip()) for x in text.split(",") if x.strip())
    except ValueError:
        raise ConfigError(f"cannot read the list '{text}'") from None


def _part(text: str) -> tuple[int, int]:
    from lmjx.errors import ConfigError

    try:
        k, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise ConfigError(f"--part '{text}': give K/N, e.g. 2/4 (the second of four parts)") from None
    return k, n


def scene_tasks(paths: list[str], robot) -> tuple:
    """The tasks of scene files, checked and placed for `robot`, each numbered by its file's
    `number`, else by the first number from 1 up that no other scene has."""
    from dataclasses import replace

    from lmjx.errors import SceneError
    from lmjx.sim.scenefile import load_scene

    tasks = [load_scene(p, robot) for p in paths]
    given: dict[int, str] = {}
    for path, t in zip(paths, tasks, strict=True):
        if t.number and t.number in given:
            raise SceneError(f"--scenes: {given[t.number]} and {path} both have number = {t.number}; give each scene "
                             "file its own number (it sets the trials' seeds)")  # fmt: skip
        given.setdefault(t.number, path)
    free = (n for n in range(1, 100) if n not in given)
    return tuple(t if t.number else replace(t, scenario=replace(t.scenario, number=next(free))) for t in tasks)


def cmd_evaluate(args: argparse.Namespace) -> int:
    from dataclasses import replace
    from pathlib import Path

    from lmjx.errors import ConfigError, LmjxError
    from lmjx.evaluation.evaluate import (
        EvalConfig,
        evaluate,
        load_maps,
        open_run,
        plots,
        report_markdown,
        scenario_label,
        scene_names,
        summarize,
    )
    from lmjx.evaluation.provenance import simulator_description
    from lmjx.evaluation.stats import rate_text
    from lmjx.planner.levers import planner_config
    from lmjx.planner.trial import resolve_simulator
    from lmjx.runtime.fileio import check_writable, write_text_atomic
    from lmjx.sim.scenecheck import check_goal

    robot = _load_robot(args)
    failures = _split(args.failures) if args.failures else tuple(robot.profile.presets)
    if not failures:
        raise ConfigError(f"the robot {robot.key} has no failure presets: give --failures (e.g. none)")
    tasks = task_set(args, bool(args.scenes))
    scenes = scene_tasks(args.scenes, robot) if args.scenes else ()
    if scenes:  # the scenes' task sets, as the records name them
        tasks = "+".join(dict.fromkeys(t.tasks for t in scenes))
    config = EvalConfig(
        failures=failures,
        scenarios=tuple(t.number for t in scenes) if scenes else _split(args.scenarios or "1,2,3", int),
        asms=_split(args.asms),
        trials=args.trials,
        seed=args.seed,
        tasks=tasks,
        part=_part(args.part),
        scenes=scenes,
    )
    config.validate()
    levers = planner_levers(args)
    planner_config("greedy", "cpu", levers)  # the planner's settings checked before anything is loaded or said
    out = Path(args.out)
    maps = load_maps(robot, config.failures, Path(args.maps or robot.maps_dir))  # before --out is made
    for s in config.scenarios:  # every goal where each map reaches (before anything is simulated)
        task = config.task(s, robot)
        for m in maps.values():
            check_goal(task, m.reach, f"{task.name} on {m.path}")
    simulates = bool(set(config.asms) - {"random"})
    sim_name, why = resolve_simulator(args.sim) if simulates else ("cpu", "random does not simulate")
    config = replace(config, planner=planner_config("greedy", sim_name, levers), backend=sim_name)
    made = not out.exists()  # --out is made here, once everything is checked
    check_writable(out / "results.json", "results")
    try:
        opened = open_run(robot, maps, config, out, args.command_line, args.allow_mixed,
                          args.registered)  # a refusal: one line  # fmt: skip
        if simulates:
            print(f"lmjx evaluate: simulator {sim_name} ({why})", file=sys.stderr)
        results = evaluate(robot, maps, config, out, say=lambda line: print(line, file=sys.stderr), opened=opened,
                           processes=args.processes)  # fmt: skip
    except LmjxError:
        if made and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # no folder left empty by a refusal
        raise
    except KeyboardInterrupt:
        _leave_interrupted(
            f"lmjx evaluate: interrupted; the trials finished are kept in {out}/results.json: rerun the same "
            "command to continue (it resumes with the trials not yet run)"
        )
    for note in moved_notes(args):  # after the run: a refusal before it stays one line
        print(note, file=sys.stderr)
    records = results.trials
    write_text_atomic(out / "report.md", report_markdown(results, config, simulator_description(sim_name), robot))
    plots(records, out)
    rows = summarize(records)
    names = scene_names(records)
    lines = [
        f"{len(records)} trial{'' if len(records) == 1 else 's'} ({config.tasks} tasks); results in "
        f"{out}/results.json, report in {out}/report.md",
        f"  simulator {sim_name} ({why}), greedy {config.planner.greedy_candidates} candidates",
        "  task time: planning (wall clock) + robot time (simulated execution), mean over the trials",
    ]
    lines += [
        f"  {r['failure']} scenario {scenario_label(r['scenario'], names)} {r['asm']:>6}: "
        f"{rate_text(r['successes'], r['trials'])}, "
        f"task {r['task_s_mean']:.1f} s"
        for r in rows
    ]
    _emit(
        args,
        {
            "tasks": config.tasks,
            "cells": rows,
            "out": str(out),
            "simulator": sim_name,
            "simulator_reason": why,
            "candidates": config.planner.greedy_candidates,
        },
        lines,
    )
    return 0
