"""`lmjx atlas`: PM and NPM+PM areas for every 2- and 3-joint lock, resumable, over all
local accelerators and optionally several hosts."""

from __future__ import annotations

import argparse
import sys

from lmjx.cli.common import (
    HDF5_SUFFIXES,
    _add_device,
    _add_distributed,
    _add_reach_options,
    _add_robot,
    _emit,
    _init_distributed,
    _leave_interrupted,
    _load_robot,
    _positive_int,
    _reach_config,
    check_suffix,
)


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "atlas",
        help="failure atlas: PM and NPM+PM areas for every 2- and 3-joint lock",
        description="For every set of locked joints of the given sizes (the Panda's 7 joints: 21 pairs, 35 "
        "triples; the UR5e's 6: 15 and 20) and K lock angles per "
        "locked joint (one drawn in each of K equal bins of the joint's range, seeded), compute the Reach-Ability "
        "map and store its labels and areas in one HDF5 file.  One IK program serves every failure, and every "
        "launch is split over all local accelerators (JAX sharding).  Resumable: progress is kept in "
        "<out>.partial after every group of maps; rerun the same command to continue.  Several hosts: start the "
        "same command on each with --coordinator HOST:PORT --num-processes N --process-id I (jax.distributed); "
        "process 0 writes the files.",
    )
    p.add_argument("--joints", default="2,3", help="numbers of locked joints, comma separated (default 2,3)")
    p.add_argument("--angles", type=_positive_int, default=3, help="K, lock angles per locked joint (default 3)")
    _add_robot(p)
    p.add_argument(
        "--out", help="HDF5 file to write (.h5; default maps/atlas.h5; another robot's: maps/<robot>/atlas.h5)"
    )
    p.add_argument("--group", type=_positive_int, default=256, help="maps per series of launches and checkpoint (256)")
    _add_reach_options(p)
    p.add_argument("--summary", help="also write a Markdown summary here (.md; its figure beside it as .png)")
    p.add_argument("--compare", action="append", metavar="ROBOT[=ATLAS]",
                   help="compute nothing but compare atlases: ROBOT a name or an MJCF, ATLAS its atlas (default "
                   "<robot's maps>/atlas.h5); repeatable; with --summary PAGE the table goes into PAGE between its "
                   "markers and the figure to img/<page>.png beside it")  # fmt: skip
    _add_distributed(p)
    p.add_argument("--no-shard", action="store_true", help="use one device only (for comparisons)")
    p.add_argument("--chunk", type=_positive_int, help="IK problems per device per launch (default by platform)")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    _add_device(p)
    p.set_defaults(run=cmd_atlas)
    return p


def cmd_atlas(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from lmjx.errors import ConfigError

    if args.compare:  # several arms' atlases side by side (lmjx/reach/atlas_compare.py)
        from lmjx.reach.atlas_compare import compare_report

        _emit(args, *compare_report(args.compare, args.summary))
        return 0

    try:
        sizes = tuple(int(x) for x in args.joints.split(",") if x.strip())
    except ValueError:
        raise ConfigError(f"--joints must be numbers of locked joints like 2,3, got '{args.joints}'") from None
    if args.out:
        check_suffix(args.out, "--out", HDF5_SUFFIXES, "the atlas is written as HDF5")
    if args.summary:
        check_suffix(args.summary, "--summary", (".md",), "the summary is written as Markdown")
    _init_distributed(args)
    import jax

    from lmjx.reach.atlas import AtlasConfig, build_atlas, expected_maps

    robot = _load_robot(args)
    out = args.out or f"{robot.maps_dir}/atlas.h5"
    reach = replace(_reach_config(args, robot), chunk=args.chunk)
    config = AtlasConfig(sizes=sizes, angles=args.angles, seed=args.seed, group=args.group, reach=reach)
    config.validate(robot)
    lead = jax.process_index() == 0
    if args.summary and lead:
        from lmjx.runtime.fileio import check_writable

        check_writable(args.summary, "summary")
    try:
        st = build_atlas(
            robot, config, out, progress=True, sharded=not args.no_shard, say=lambda line: print(line, file=sys.stderr)
        )
    except KeyboardInterrupt:
        _leave_interrupted(
            f"lmjx atlas: interrupted; finished groups are kept in {out}.partial: rerun the same command to continue "
            "(it resumes where this one stopped)"
        )
    if not lead:
        return 0
    if args.summary:
        from pathlib import Path

        from lmjx.reach.atlas_report import write_summary

        md = Path(args.summary)
        write_summary(st, md, md.with_suffix(".png"))
    areas = st.areas()
    session = st.run["sessions"][-1]
    summary = {
        "robot": robot.key,
        "out": out,
        "maps": st.n,
        "expected_maps": expected_maps(sizes, args.angles, robot.nq),
        "complete": bool(st.done.all()),
        "device": session["device"],
        "devices": session["devices"],
        "processes": session["processes"],
        "seconds": session["seconds"],
        "compile_s": session.get("compile_s", 0.0),
        "maps_this_run": session["maps"],
        "pm_zero": int((areas["pm"] == 0).sum()),
        "rescued_by_npm": int(((areas["pm"] == 0) & (areas["npm_pm"] > 0)).sum()),
    }
    lines = [
        f"atlas {out} ({robot.key}): {st.n} maps ({summary['maps_this_run']} computed now) on {summary['devices']} "
        f"device(s) of {summary['processes']} process(es), {summary['device']}",
        f"  {summary['seconds']:.1f} s (compile {summary['compile_s']:.1f} s)",
        f"  PM = 0 in {summary['pm_zero']} maps; NPM rescues {summary['rescued_by_npm']} of them",
    ]
    if args.summary:
        lines.append(f"  summary written to {args.summary}")
    _emit(args, summary, lines)
    return 0
