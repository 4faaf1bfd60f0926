"""`lmjx robots` (the shipped robots) and `lmjx robot check` (an MJCF against lmjx's
contract, docs/ROBOTS.md); `lmjx robot import` lives in robot_import.py."""

from __future__ import annotations

import argparse
import json
import sys

from lmjx.cli import robot_import
from lmjx.cli.common import EXIT_USAGE, _emit, _Parser


def add_parser(sub: argparse._SubParsersAction) -> list[argparse.ArgumentParser]:
    p = sub.add_parser(
        "robots",
        help="the shipped robots, their joints and failure presets",
        description="List the robots lmjx ships (use them with --robot NAME): joints, limits, interaction points and "
        "failure presets.  Any other arm: --robot PATH to an MJCF that meets docs/ROBOTS.md.",
    )
    p.add_argument("--json", action="store_true", help="print JSON on stdout")
    p.set_defaults(run=cmd_robots)

    r = sub.add_parser(
        "robot",
        help="check a robot description (MJCF) against lmjx's contract, or import one from a URDF",
        description="lmjx robot check PATH: validate an MJCF against docs/ROBOTS.md; every missing or inconsistent "
        "part is named on a line of its own (exit status 2); a file that passes is summarised.  lmjx robot import "
        "SRC --out ARM.xml: write such an MJCF from a URDF or an MJCF with meshes.",
    )
    rsub = r.add_subparsers(dest="robot_command", required=True, parser_class=_Parser, metavar="ACTION")
    c = rsub.add_parser("check", help="validate an MJCF against docs/ROBOTS.md", description="Validate an MJCF.")
    c.add_argument("path", help="the MJCF file (.xml), or a shipped robot's name")
    c.add_argument("--json", action="store_true", help="print JSON on stdout")
    c.set_defaults(run=cmd_robot_check)
    robot_import.add_parser(rsub)
    return [p, r]


def cmd_robots(args: argparse.Namespace) -> int:
    from lmjx.model.robot import ROBOTS, load_robot

    rows = []
    for name in ROBOTS:
        r = load_robot(name)
        rows.append(
            {
                "name": name,
                "description": r.profile.description,
                "file": str(r.path),
                "joints": r.nq,
                "joint_names": list(r.joint_names),
                "interaction_points": sorted(r.interaction_points),
                "presets": {k: {f"J{j}": a for j, a in sorted(v.items())} for k, v in r.profile.presets.items()},
                "maps": r.maps_dir,
                "model_hash": r.model_hash,
            }
        )
    lines = []
    for row in rows:
        presets = "; ".join(
            f"{k} (" + ", ".join(f"{j}={a:.4g}" for j, a in v.items()) + ")" for k, v in row["presets"].items()
        )
        lines += [
            f"{row['name']}{' (default)' if row['name'] == 'panda' else ''}: {row['description']}",
            f"  {row['joints']} joints: {', '.join(row['joint_names'])}",
            f"  failure presets: {presets or 'none yet'}",
            f"  interaction points: {', '.join(row['interaction_points'])}",
            f"  {row['file']}; maps in {row['maps']}/",
        ]
    lines.append("any other arm: --robot PATH to an MJCF that meets docs/ROBOTS.md (lmjx robot check PATH)")
    _emit(args, {"robots": rows}, lines)
    return 0


def cmd_robot_check(args: argparse.Namespace) -> int:
    from lmjx.model.robot import check_robot, load_robot, resolve_robot

    key, path = resolve_robot(args.path)
    problems = check_robot(path)
    if problems:
        if args.json:
            print(json.dumps({"path": str(path), "ok": False, "problems": problems}, indent=2))
        for p in problems:
            print(f"{path}: {p}", file=sys.stderr)
        return EXIT_USAGE
    r = load_robot(key)
    summary = {
        "path": str(path),
        "ok": True,
        "name": r.name,
        "joints": r.nq,
        "joint_names": list(r.joint_names),
        "capsules": len(r.arm.cap_r),
        "checked_pairs": len(r.arm.self_pairs),
        "interaction_points": sorted(r.interaction_points),
        "tool_body": r.tool_body_name,
        "task_scale": r.profile.task_scale,
        "model_hash": r.model_hash,
    }
    lines = [
        f"{path}: an lmjx robot: '{r.name}', {r.nq} hinge joints ({', '.join(r.joint_names)}), "
        f"{summary['capsules']} capsules ({summary['checked_pairs']} self-collision pairs checked)",
        f"  tool body {r.tool_body_name}; interaction points {', '.join(summary['interaction_points'])}; "
        f"scenarios scaled by {r.profile.task_scale:g}",
    ]
    _emit(args, summary, lines)
    return 0
