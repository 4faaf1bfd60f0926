"""`lmjx scenarios`: each evaluation scenario's description and picture (a MuJoCo rendering
beside a top-down diagram; the diagram alone where there is no OpenGL); `--check FILE`: a
scene file checked (its keys and geometry; with --map, the goal against the map)."""

from __future__ import annotations

import argparse

from lmjx.cli.common import SEED_RANGE, _add_robot, _load_robot, _seed

# Set by `lmjx.cli.main` when MUJOCO_GL named an OpenGL that is not installed (and was unset).
gl_note: str | None = None


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "scenarios",
        help="pictures and descriptions of the three evaluation scenarios; --check a scene file",
        description="Print each scenario's description and write <out>/scenario<N>.png: a MuJoCo rendering of the "
        "scene (the arm at its park pose for case2, or for no failure if the robot has no case2) beside a top-down "
        "diagram of the layout; the scenarios sit where they do for the Panda, scaled to the robot's size.  "
        "Rendering needs OpenGL "
        "(on a headless machine: MUJOCO_GL=egl where EGL is installed, else MUJOCO_GL=osmesa with OSMesa); without it "
        "only the diagram is drawn.",
    )
    p.add_argument("--out", default=".", help="folder for the pictures (default: the current folder)")
    p.add_argument(
        "--check",
        metavar="FILE",
        help="check a scene file instead (TOML, docs/SCENES.md): its keys, its objects apart, on the table and clear "
        "of the arm's base, and with --map the goal where the map reaches; draws nothing",
    )
    p.add_argument("--map", metavar="FILE", help="with --check: the map whose reach the goal must lie in")
    p.add_argument("--json", action="store_true", help="with --check: print a JSON summary on stdout")
    p.add_argument("--seed", type=_seed, default=0, help=f"layout seed, {SEED_RANGE} (default 0)")
    p.add_argument("--tasks", choices=("paper", "hard"), default="paper", help="the task set (default paper)")
    _add_robot(p)
    p.set_defaults(run=cmd_scenarios)
    return p


def cmd_check(args: argparse.Namespace) -> int:
    """`--check FILE`: the scene's summary, or a one-line error."""
    from lmjx.cli.common import _emit
    from lmjx.mapfile.read import load_map
    from lmjx.sim.scenefile import load_scene

    m = load_map(args.map, _load_robot(args) if args.robot else None) if args.map else None
    robot = m.robot if m is not None else _load_robot(args)
    task = load_scene(args.check, robot, m)
    sc = task.scenario
    checked = "objects apart, on the table, clear of the arm's base" + (f"; goal reached on {args.map}" if m else "")
    summary = {
        "scene": args.check,
        "name": task.name,
        "robot": task.robot,
        "task_set": sc.tasks,
        "number": sc.number,
        "movable": len(sc.movable),
        "fixed": len(sc.fixed),
        "cylinders": sum(b.shape == "cylinder" for b in (*sc.movable, *sc.fixed)),
        "goal_center": list(sc.goal_center),
        "goal_size": [2 * h for h in sc.goal_half],
        "budget": sc.budget,
        "map": args.map,
    }
    cylinders = summary["cylinders"]
    kind, round_ = ("objects", f" ({cylinders} of them cylinders)") if cylinders else ("boxes", "")
    lines = [
        f"{args.check}: ok ({task.name}: the target, {len(sc.obstacles)} movable {kind}, {len(sc.fixed)} fixed "
        f"obstacle{'' if len(sc.fixed) == 1 else 's'}{round_}, a budget of {sc.budget} actions, placed for "
        f"{task.robot})",
        f"  checked: {checked}" + ("" if m else "; give --map to check the goal against a map"),
    ]
    _emit(args, summary, lines)
    return 0


def cmd_scenarios(args: argparse.Namespace) -> int:
    if args.check is not None:
        return cmd_check(args)
    if args.map is not None or args.json:
        from lmjx.errors import ConfigError

        raise ConfigError("--map and --json go with --check FILE")
    import sys
    from pathlib import Path

    from lmjx.model.failure import parse_failure
    from lmjx.planner.clearance import park_pose
    from lmjx.runtime.fileio import check_writable
    from lmjx.sim.figure import scenario_picture
    from lmjx.sim.render import gl_problem
    from lmjx.sim.scenarios import SCENARIOS, resolve_task

    out = Path(args.out)
    robot = _load_robot(args)
    q = park_pose(robot, parse_failure("case2" if "case2" in robot.profile.presets else "none", robot))
    tasks = {n: resolve_task(n, robot, args.tasks) for n in sorted(SCENARIOS)}
    check_writable(out / "scenario1.png", "pictures")  # the folder made once everything is checked
    problem = gl_note or gl_problem()
    if problem is not None:
        print(f"note: drawing the diagrams only: {problem}", file=sys.stderr)
    for n, task in tasks.items():
        sc = task.scenario
        path = out / f"scenario{n}.png"
        scenario_picture(robot, sc, task.layout(args.seed), q, path, with_render=problem is None)
        head = f"scenario {n} ({args.tasks} tasks, {sc.budget} actions): {sc.title}"
        print(f"{head}\n  {sc.description}\n  picture: {path}")
    return 0
