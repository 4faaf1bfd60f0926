"""`lmjx build-map`: a failure's Reach-Ability map and kinodynamic edge bundle in one HDF5
file (paper Algorithms 1-2), resumable after an interrupt."""

from __future__ import annotations

import argparse
import sys

from lmjx.cli.common import (
    HDF5_SUFFIXES,
    SEED_RANGE,
    _add_device,
    _add_distributed,
    _add_overwrite,
    _add_robot,
    _emit,
    _failure_help,
    _init_distributed,
    _leave_interrupted,
    _load_robot,
    _positive_float,
    _positive_int,
    _seed,
    check_suffix,
)


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "build-map",
        help="Reach-Ability map + kinodynamic edge bundle in one HDF5 file (paper Algorithms 1-2)",
        description="Build a failure's map: the Reach-Ability map, then N Monte Carlo edges: from a reachable cell "
        "and an interaction point, a constant twist followed for a sampled duration with the arm's dynamics "
        "(tau = M qdd + C qd + g + friction), rejecting any edge that breaks a position, velocity, acceleration "
        "or torque limit or collides with the table or itself.  Valid edges are stored with every state and a "
        "spatial index per cell (schema: maps/README.md).  Any number of edges: they are computed and saved in "
        "chunks (bounded memory) into <out>.partial, and the map is assembled from them at the end; a preflight "
        "first says how large and how long; an interrupted build (Ctrl-C, a kill) continues when the same command "
        "runs again, and a failed one keeps <out>.partial only where it holds computed edges (and says so).  A "
        "map already at --out that this command built (the same robot, failure, parameters and seed) is kept, "
        "and the command exits 0 at once; any other file there is replaced only with --overwrite.  Every local "
        "GPU shares the work, each beyond the first from a process of its own (LMJX_PEERS=0: all from this one); "
        "several hosts: the same command on each with --coordinator HOST:PORT --num-processes N --process-id I.",
    )
    p.add_argument("--failure", required=True, help=_failure_help())
    _add_robot(p)
    p.add_argument(
        "--edges",
        type=_positive_int,
        help="edges to sample, up to 50,000,000 (default: 10,000 on a CPU, 100,000 on a GPU); only valid ones "
        "are stored",
    )
    p.add_argument(
        "--out", help="map file to write (.h5; default maps/<failure>.h5; another robot's: maps/<robot>/<failure>.h5)"
    )
    _add_overwrite(p, "a map or another file")
    p.add_argument("--seed", type=_seed, default=0, help=f"random seed for the map and the edges, {SEED_RANGE} "
                   "(default 0)")  # fmt: skip
    p.add_argument("--cell", type=_positive_float, default=0.02, help="reach cell edge in metres (default 0.02)")
    p.add_argument(
        "--chunk",
        type=_positive_int,
        help="edges computed and saved at a time (default: by platform); not part of the result",
    )
    p.add_argument(
        "--compile-presets",
        action=argparse.BooleanOptionalAction,
        help="also compile the programs of the robot's other preset failures and none, once per machine, so that "
        "their builds load them (default: on a GPU, not on a CPU, where it takes minutes of the cores)",
    )
    p.add_argument("--yes", action="store_true", help="start even when the preflight estimates more than a day of work")
    p.add_argument("--no-shard", action="store_true", help="use one device only (for comparisons)")
    _add_distributed(p)
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    _add_device(p)
    p.set_defaults(run=cmd_build_map)
    return p


def cmd_build_map(args: argparse.Namespace) -> int:
    from lmjx.api import build_map, default_map_path
    from lmjx.edges.compiling import InterruptedAfterMap
    from lmjx.edges.stream import partial_path
    from lmjx.model.failure import parse_failure

    if args.out:
        check_suffix(args.out, "--out", HDF5_SUFFIXES, "the map is written as HDF5")
    _init_distributed(args)
    import jax

    robot = _load_robot(args)
    failure = parse_failure(args.failure, robot)
    out = args.out or str(default_map_path(failure, robot))
    try:
        b = build_map(
            failure, robot, out=out, edges=args.edges, seed=args.seed, cell=args.cell, chunk=args.chunk,
            sharded=not args.no_shard, yes=args.yes, progress=True, say=lambda line: print(line, file=sys.stderr),
            compile_presets=args.compile_presets, overwrite=args.overwrite,
        )  # fmt: skip
    except InterruptedAfterMap:
        _leave_interrupted(
            f"lmjx build-map: interrupted; the map is written to {out}; the other failures' programs not compiled "
            "yet compile when they are built"
        )
    except KeyboardInterrupt:
        partial = partial_path(out)
        kept = (
            f"what was computed is kept in {partial}: rerun the same command to continue (it resumes where this one "
            "stopped), or remove it"
            if partial.exists()
            else "nothing was computed that a rerun could use"
        )
        _leave_interrupted(f"lmjx build-map: interrupted; nothing was written to {out}; {kept}")
    if jax.process_index() != 0:
        return 0
    if not b.built:
        e = b.edges
        _emit(args, b.summary(), [
            f"{out} already holds this map (the same robot, failure, parameters and seed; {e['edges_valid']:,} valid "
            f"edges of {e['edges_sampled']:,}, built on {e['device']}): kept, nothing computed; --overwrite builds "
            "it again"
        ])  # fmt: skip
        return 0
    summary, s, area = b.summary(), b.edges, b.reach["area_m2"]
    rej = ", ".join(f"{k} {v}" for k, v in s["rejected"].items() if v)
    lines = [
        f"{robot.key}, failure {failure.describe()} on {s['device']} ({s['devices']} device(s), "
        f"{s['processes']} process(es)): "
        f"map written to {out}",
        f"  reach: PM {area['pm']:.4f} m^2, NPM+PM {area['npm_pm']:.4f} m^2 ({b.reach['seconds']:.2f} s)",
        f"  edges: {s['edges_valid']:,} valid of {s['edges_sampled']:,} sampled; rejected: {rej or 'none'}",
        f"  rollouts: {s['edge_steps']:,} edge-steps in {s['rollout_seconds']:.2f} s "
        f"({s['edge_steps_per_s'] / 1e6:.2f} M/s); edges {s['seconds']:.2f} s "
        f"(of which writing the map alongside {s['write_seconds']:.1f} s, its index {s['finish_seconds']:.1f} s)",
        f"  compile: {summary['compile_seconds']:.1f} s ("
        + ", ".join(f"{k} {v:.1f} s" for k, v in summary["compile_seconds_by_stage"].items())
        + (", side by side" if sum(summary["compile_seconds_by_stage"].values()) > summary["compile_seconds"] + 0.05
           else "")
        + ")"
        + _later(summary["compiled_for_later"]),
        f"  storage: {summary['bytes_per_state']:.1f} bytes per stored state "
        f"({summary['raw_bytes_per_state']:.0f} uncompressed)",
    ]
    _emit(args, summary, lines)
    return 0


def _later(later: dict | None) -> str:
    """The compile line's account of the other failures' programs (`lmjx.edges.compiling`)."""
    if not later:
        return ""
    done = f"{len(later['compiled'])} compiled, {len(later['cached'])} already cached"
    left = f", {later['left']} left" if later["left"] else ""
    return f"; for later builds of {', '.join(later['failures'])}: {done}{left} ({later['seconds']:.1f} s)"
