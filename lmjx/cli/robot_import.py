"""`lmjx robot import`: write an lmjx robot MJCF from a URDF or an MJCF with meshes, and say
how tight its fitted capsules are."""

from __future__ import annotations

import argparse

from lmjx.cli.common import EXIT_USAGE, _add_overwrite, _emit, _positive_float, check_not_there


def add_parser(rsub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    c = rsub.add_parser(
        "import",
        help="write an lmjx robot MJCF from a URDF or an MJCF with meshes",
        description="Import an arm: its links' collision geometry (meshes, primitives) is enclosed by fitted "
        "capsules, its limits are taken from the source (a missing one is named, with the flag that supplies "
        "it), the flange, tcp and interaction-point sites are placed, and the table and actuators added; the "
        "result passes lmjx robot check.  How tight the capsules are (vertices covered, volume over the "
        "geometry's convex hulls) is printed and kept in the file's header.  Method: lmjx/model/robot_import.py.",
    )
    c.add_argument("src", help="the URDF (.urdf) or MJCF (.xml); package:// mesh paths resolve from its folder up")
    c.add_argument("--out", required=True, help="the MJCF to write (.xml)")
    _add_overwrite(c, "an MJCF")
    c.add_argument("--tcp", help="LINK[:x,y,z]: the grasp point, in LINK's frame (default: the last arm link, 0,0,0)")
    c.add_argument("--flange", help="LINK: the tool flange's frame (default: the last arm link's)")
    c.add_argument("--qd-max", help="velocity limit(s) [rad/s]: one value, or one per arm joint comma-separated "
                   "(default: the source's)")  # fmt: skip
    c.add_argument("--qdd-max", help="acceleration limit(s) [rad/s^2], one value or one per joint (required: "
                   "URDFs carry none)")  # fmt: skip
    c.add_argument("--tau-max", help="torque limit(s) [Nm], one value or one per joint (default: the source's effort)")
    c.add_argument("--limit", type=_positive_float, help="V: the range +-V rad of every continuous (unlimited) joint")
    c.add_argument("--ready", help="q1,...,qn: the park pose (lmjx_ready) [rad]; default: lmjx chooses one")
    c.add_argument("--ip", action="append", default=[], metavar="NAME=LINK:x,y,z[:r]",
                   help="place (or move) the interaction point ip_NAME; repeatable")  # fmt: skip
    c.add_argument("--name", help="the model's name (default lmjx_<source file's stem>)")
    c.add_argument("--gripper", metavar="2f85[:z]", help="attach a gripper stand-in at the flange (2f85: the "
                   "UR5e's, a Robotiq 2F-85 opened to 85 mm, tcp 0.145 m out) where the flange link's geometry "
                   "ends along its axis, or z m along it; the tcp between its fingertips (no --tcp)")  # fmt: skip
    c.add_argument("--preset", action="append", default=[], metavar="NAME=J2=0.3,J4=-1.5",
                   help="a failure preset written into the file (--failure NAME); repeatable")  # fmt: skip
    c.add_argument("--json", action="store_true", help="print JSON on stdout")
    c.set_defaults(run=cmd_robot_import)
    return c


def cmd_robot_import(args: argparse.Namespace) -> int:
    from pathlib import Path

    from lmjx.errors import ConfigError
    from lmjx.model.robot import check_robot
    from lmjx.model.robot_import import ImportOptions, command_line, import_robot
    from lmjx.runtime.fileio import check_writable

    out = Path(args.out)
    if out.suffix.lower() != ".xml":
        raise ConfigError(f"--out {out}: an MJCF is written to a .xml file")
    check_not_there(out, args.overwrite, "robot")
    check_writable(out, "robot")
    opt = ImportOptions(
        tcp=args.tcp,
        flange=args.flange,
        qd_max=args.qd_max,
        qdd_max=args.qdd_max,
        tau_max=args.tau_max,
        limit=args.limit,
        name=args.name,
        ready=args.ready,
        ips=list(args.ip),
        gripper=args.gripper,
        presets=list(args.preset),
    )
    r = import_robot(args.src, out, opt, command_line())
    problems = check_robot(out)
    summary = {
        "out": str(out),
        "joints": r.joints,
        "welded": r.welded,
        "excluded_pairs": [list(p) for p in r.excluded],
        "links": [
            {
                "link": f.body,
                "capsules": len(f.capsules),
                "points": f.points,
                "covered": f.covered,
                "geometry_volume_l": round(1e3 * f.geometry_volume, 4),
                "capsule_volume_l": round(1e3 * f.capsule_volume, 4),
                "ratio": round(f.overestimate, 3),
            }
            for f in r.fits
        ],
        "check": problems or "passes",
    }
    lines = [f"{out}: {len(r.joints)} arm joints ({', '.join(r.joints)})"]
    lines += [f"  welded: {w}" for w in r.welded]
    lines += ["  capsules per link (vertices covered; volume of the union over the geometry's convex hulls):"]
    lines += [
        f"    {f.body}: {len(f.capsules)}, {100 * f.covered:.1f} % of {f.points} points, "
        f"{1e3 * f.capsule_volume:.3f} l over {1e3 * f.geometry_volume:.3f} l ({f.overestimate:.2f}x)"
        for f in r.fits
    ]
    lines += ["  self-collision exclusions: " + ", ".join(f"{a}-{b}" for a, b in r.excluded)]
    lines += [f"  lmjx robot check: {'passes' if not problems else '; '.join(problems)}"]
    _emit(args, summary, lines)
    return 0 if not problems else EXIT_USAGE
