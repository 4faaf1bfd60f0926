"""`lmjx reach`: one failure's Reach-Ability map (paper Algorithm 1), its summary, and
optionally the map file and a heatmap."""

from __future__ import annotations

import argparse

from lmjx.cli.common import (
    HDF5_SUFFIXES,
    _add_device,
    _add_overwrite,
    _add_reach_options,
    _add_robot,
    _emit,
    _failure_help,
    _load_robot,
    _reach_config,
    check_not_there,
    check_suffix,
    figure_format,
)


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "reach",
        help="Reach-Ability map of a failure (paper Algorithm 1)",
        description="Compute which cells of the task plane the arm can grasp at (PM), only push or poke (NPM), or "
        "not reach, with a given failure.  Failures: none, a preset of the robot (the Panda's case1: J3, J5, J7 "
        "locked; case2: J6, J7 locked; lmjx robots lists every robot's) or an explicit list such as "
        "'J2=0.3,J4=-1.5' (radians).",
    )
    p.add_argument("--failure", required=True, help=_failure_help())
    _add_robot(p)
    _add_reach_options(p)
    p.add_argument("--out", help="write the map to this HDF5 file (.h5; schema in maps/README.md)")
    _add_overwrite(p, "a file")
    p.add_argument(
        "--png", help="write a heatmap (raw and smoothed) to this file; the format from its extension (.png, .pdf, "
        ".svg, .jpg, ...)"
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    _add_device(p)
    p.set_defaults(run=cmd_reach)
    return p


def cmd_reach(args: argparse.Namespace) -> int:
    from lmjx.model.failure import parse_failure
    from lmjx.runtime.fileio import check_writable

    robot = _load_robot(args)
    failure = parse_failure(args.failure, robot)
    config = _reach_config(args, robot)
    config.validate(robot)
    if args.out:
        check_suffix(args.out, "--out", HDF5_SUFFIXES, "the map is written as HDF5")
        check_not_there(args.out, args.overwrite, "reach map")
        check_writable(args.out, "map file")
    if args.png:
        fmt = figure_format(args.png, "--png")
        check_writable(args.png, "heatmap")
    from lmjx.reach.reachability import reach_map

    result = reach_map(failure, config, robot=robot, progress=True)
    if args.out:
        from lmjx.mapfile.write import write_reach_map

        write_reach_map(args.out, result, robot, overwrite=args.overwrite)
    if args.png:
        from lmjx.reach.plots import reach_heatmap

        reach_heatmap(result, args.png, fmt)
    s = result.summary()
    a, raw = s["area_m2"], s["area_raw_m2"]
    lines = [
        f"failure {failure.describe()}: {s['cells']} cells of {s['cell_m'] * 100:g} cm on {s['device']}",
        f"  PM area      {a['pm']:.4f} m^2 (raw {raw['pm']:.4f})",
        f"  NPM+PM area  {a['npm_pm']:.4f} m^2 (raw {raw['npm_pm']:.4f})",
        f"  {s['problems']} IK problems in {s['seconds']:.2f} s (+ {s['compile_seconds']:.1f} s compile)",
    ]
    if args.out:
        lines.append(f"  map written to {args.out}")
    if args.png:
        lines.append(f"  heatmap written to {args.png}")
    _emit(args, s, lines)
    return 0
