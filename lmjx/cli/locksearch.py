"""`lmjx lock-search`: Reach-Ability areas over a grid of lock angles, the 'best' lock
(smallest PM, then largest NPM+PM; a warning when it reaches nothing) and optionally the
lock closest to given area ratios."""

from __future__ import annotations

import argparse
import json

from lmjx.cli.common import (
    _add_device,
    _add_reach_options,
    _add_robot,
    _emit,
    _load_robot,
    _positive_int,
    _reach_config,
    check_suffix,
    figure_format,
    warn,
)


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "lock-search",
        help="Reach-Ability areas over a grid of lock angles",
        description="For the given locked joints, compute a full Reach-Ability map at every combination of lock "
        "angles on a grid spread over the joints' ranges, and report the PM and NPM+PM areas.  The lock with the "
        "smallest PM area (ties: largest NPM+PM) is reported as 'best'; this is how case2's angles were chosen.",
    )
    p.add_argument("--joints", required=True, help="locked joints to sweep, e.g. J6,J7")
    _add_robot(p)
    p.add_argument("--grid", type=_positive_int, default=9, help="angles per joint (default 9)")
    p.add_argument("--base", default="none", help="further joints held locked during the sweep, e.g. 'J3=0'")
    p.add_argument(
        "--match",
        metavar="PM_RATIO,NPM_RATIO",
        help="also pick the lock whose PM and NPM+PM areas relative to no failure are closest to these ratios "
        "(the paper's case 1: 0.7294,0.9239, i.e. 0.62/0.85 and 0.85/0.92); computes the no-failure map too",
    )
    _add_reach_options(p)
    p.add_argument("--out", help="write every grid point's areas to this JSON file (.json)")
    p.add_argument(
        "--png", help="write PM and NPM+PM heatmaps over the grid (two joints only); the format from the file's "
        "extension (.png, .pdf, .svg, .jpg, ...)"
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    _add_device(p)
    p.set_defaults(run=cmd_lock_search)
    return p


def _parse_match(text: str) -> tuple[float, float]:
    from lmjx.errors import ConfigError

    try:
        match = tuple(float(v) for v in text.split(","))
    except ValueError:
        match = ()
    if len(match) != 2 or not all(0 <= v <= 2 for v in match):
        raise ConfigError(f"--match takes two ratios such as 0.7294,0.9239, got '{text}'")
    return match[0], match[1]


def cmd_lock_search(args: argparse.Namespace) -> int:
    from lmjx.errors import ConfigError
    from lmjx.model.failure import parse_failure
    from lmjx.reach.locksearch import lock_grid, lock_search, parse_joints
    from lmjx.runtime.fileio import check_writable, write_text_atomic

    robot = _load_robot(args)
    joints = parse_joints(args.joints, robot)
    base = parse_failure(args.base, robot)
    clash = set(joints) & set(base.locked_joints)
    if clash:
        raise ConfigError(f"J{min(clash)} is both swept (--joints) and held (--base)")
    if len(joints) + len(base.locked) >= robot.nq:
        raise ConfigError("the sweep would lock every joint")
    config = _reach_config(args, robot)
    config.validate(robot)
    if args.png and len(joints) != 2:
        raise ConfigError("--png draws a 2-D grid: give exactly two --joints")
    if args.out:
        check_suffix(args.out, "--out", (".json",), "the results are written as JSON")
        check_writable(args.out, "results file")
    if args.png:
        fmt = figure_format(args.png, "--png")
        check_writable(args.png, "plot")
    match = _parse_match(args.match) if args.match else None
    grids = tuple(lock_grid(robot, j, args.grid) for j in joints)
    res = lock_search(joints, grids, config, robot=robot, base=base, progress=True)
    angles, pm, npm = res.best()

    def named(values: tuple[float, ...]) -> dict[str, float]:
        return {f"J{j}": round(a, 4) for j, a in zip(joints, values, strict=True)}

    def text(values: tuple[float, ...]) -> str:
        return ", ".join(f"J{j}={a:.4f}" for j, a in zip(joints, values, strict=True))

    summary = {
        "joints": [f"J{j}" for j in joints],
        "base": base.spec,
        "grid": [[round(float(v), 4) for v in g] for g in grids],
        "best": {**named(angles), "pm_m2": pm, "npm_pm_m2": npm},
        "best_reaches_nothing": npm <= 0,
        "points": res.rows(),
        "seconds": round(res.seconds, 3),
    }
    extra = []
    angles_for_plot = angles
    if match is not None:
        from lmjx.reach.reachability import reach_map

        ref = reach_map(parse_failure("none", robot), config, robot=robot).areas()
        m_angles, m_pm, m_npm = res.closest(match[0], match[1], ref)
        summary["match"] = {"ratios": list(match), "reference_m2": ref, **named(m_angles), "pm_m2": m_pm,
                            "npm_pm_m2": m_npm}  # fmt: skip
        extra.append(
            f"closest to ratios {match[0]:g}, {match[1]:g} of no failure (PM {ref['pm']:.4f}, NPM+PM "
            f"{ref['npm_pm']:.4f} m^2): {text(m_angles)}: PM {m_pm:.4f} m^2, NPM+PM {m_npm:.4f} m^2"
        )
        angles_for_plot = m_angles
    if args.out:
        write_text_atomic(args.out, json.dumps(summary, indent=2) + "\n")
    if args.png:
        from lmjx.reach.plots import lock_search_plot

        lock_search_plot(
            grids[0], grids[1], res.pm, res.npm_pm, (f"J{joints[0]}", f"J{joints[1]}"), angles_for_plot, args.png, fmt
        )
    width = max(len(k) for k in res.rows()[0])
    lines = ["  ".join(k.rjust(width) for k in res.rows()[0])]
    lines += ["  ".join(f"{v}".rjust(width) for v in row.values()) for row in res.rows()]
    lines.append(f"best (smallest PM, then largest NPM+PM): {text(angles)}: PM {pm:.4f} m^2, NPM+PM {npm:.4f} m^2")
    lines += extra
    if npm <= 0:
        warn(
            "lock-search",
            f"the best lock ({text(angles)}) reaches nothing (PM and NPM+PM areas 0), as every lock without PM "
            "on this grid does; choose one from the table, or use --match",
        )
    _emit(args, summary, lines)
    return 0
