"""`lmjx info`: validate a map file and describe what is in it (the states stay in the
file: a map of any size answers at once); with --verify, first read the whole file and
check every chunk's checksum and the arrays against each other (`lmjx.mapfile.verify`)."""

from __future__ import annotations

import argparse
import sys

from lmjx.cli.common import EXIT_DAMAGED, _add_robot, _emit, _load_robot


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "info",
        help="what is in a map file",
        description="Validate a map file and describe its contents.  Without --verify only what the description "
        "needs is read (not the edges' states); --verify reads every chunk of every dataset, checks its checksum "
        "(HDF5's Fletcher-32) and the arrays against each other, prints one line per problem on stderr and exits "
        "with status 1 when it finds any (2: not a map file at all).",
    )
    p.add_argument("path", help="an lmjx map file (.h5)")
    _add_robot(p, from_map=True)
    p.add_argument(
        "--verify",
        action="store_true",
        help="read and check the whole file first: every chunk's checksum, the offsets, lengths and index ranges; "
        "exit status 1 if anything is damaged",
    )
    p.add_argument("--json", action="store_true", help="print JSON on stdout")
    p.set_defaults(run=cmd_info)
    return p


def cmd_info(args: argparse.Namespace) -> int:
    from lmjx.mapfile.openable import check_map_path

    check_map_path(args.path)  # (a path that is no map: said before the heavy imports)
    from lmjx.mapfile.read import load_map

    verified = None
    if args.verify:
        from lmjx.mapfile.verify import verify_map

        verified = verify_map(args.path)
        if verified.problems:
            for problem in verified.problems:
                print(f"lmjx info: {args.path}: {problem}", file=sys.stderr)
            return EXIT_DAMAGED
    robot = _load_robot(args) if args.robot else None  # None: the robot the map names
    m = load_map(args.path, robot, lazy=True)
    assert m.robot is not None
    info: dict = {
        "path": str(m.path),
        "robot": m.robot.key,
        "schema_version": int(m.attrs["schema_version"]),
        "lmjx_version": str(m.attrs["lmjx_version"]),
        "robot_model_hash": str(m.attrs["robot_model_hash"]),
        "failure": m.failure.spec,
        "locked": {f"J{j}": a for j, a in m.failure.locked},
        "contents": str(m.attrs["contents"]),
    }
    lines = [
        f"{m.path}: lmjx map, schema {info['schema_version']}, written by lmjx {info['lmjx_version']}",
        f"  robot {m.robot.key} ({m.robot.profile.description or m.robot.name}), failure {m.failure.describe()}",
    ]
    if m.reach is not None:
        r = m.reach
        s = r.summary()
        info["reach"] = {k: s[k] for k in ("cell_m", "area_m2", "area_raw_m2", "plane_m2", "cells", "seed", "device")}
        info["reach"]["grid"] = [len(r.ys), len(r.xs)]
        lines += [
            f"  reach map: {len(r.ys)} x {len(r.xs)} cells of {r.config.cell * 100:g} cm, seed {r.config.seed}",
            f"    PM {s['area_m2']['pm']:.4f} m^2, NPM+PM {s['area_m2']['npm_pm']:.4f} m^2 (smoothed)",
        ]
    if m.edges is not None:
        b = m.edges
        bs = b.summary()
        info["edges"] = {
            "sampled": bs["edges_sampled"],
            "valid": bs["edges_valid"],
            "states": bs["states"],
            "rejected": bs["rejected"],
            "bytes_per_state": float(m.edges_attrs.get("bytes_per_state", float("nan"))),
            "seed": b.config.seed,
        }
        lines += [
            f"  edges: {bs['edges_valid']:,} valid of {bs['edges_sampled']:,} sampled, {bs['states']:,} states, "
            f"dt {b.config.dt:g} s, seed {b.config.seed}",
            f"    {info['edges']['bytes_per_state']:.1f} bytes per stored state; spatial index over "
            f"{int((b.index_offset[1:] > b.index_offset[:-1]).sum())} cells",
        ]
    if verified is not None:
        info["verified"] = verified.summary()
        missing = f"; {len(verified.unchecked)} chunked datasets have no checksum (a map of an earlier lmjx)"
        lines.append(
            f"  verified: {verified.datasets} datasets read, {verified.chunks:,} chunks "
            f"({verified.stored_bytes / 1e6:.1f} MB) decoded, the checksums of {verified.checksummed} datasets "
            "and the arrays' consistency checked" + (missing if verified.unchecked else "")
        )
    else:
        lines.append("  (lmjx info --verify reads every chunk and checks its checksum)")
    _emit(args, info, lines)
    return 0
