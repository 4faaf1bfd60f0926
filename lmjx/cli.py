"""The `lmjx` command line.

Parses arguments, validates them at the boundary, calls the library and prints results
(human text, or JSON with --json on stdout; progress on stderr).  User mistakes end with a
one-line error and exit status 2, an interrupt with status 130; neither leaves a partial
output file.  Heavy imports (JAX, MuJoCo) happen only once a command runs, so --help is
instant and --device can still choose the platform.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Sequence
from typing import NoReturn

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return v


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {text}")
    return v


def _add_robot(p: argparse.ArgumentParser, from_map: bool = False) -> None:
    default = "the robot the map was built for" if from_map else "panda"
    p.add_argument(
        "--robot",
        metavar="NAME|PATH",
        help=f"the arm: a shipped robot's name (panda, ur5e; see lmjx robots) or the path of an MJCF that meets "
        f"docs/ROBOTS.md (check it with lmjx robot check PATH) (default: {default})",
    )


def _load_robot(args: argparse.Namespace):
    """The robot --robot names (the Panda when it is not given)."""
    from .robot import load_robot

    return load_robot(args.robot)


def _failure_help(what: str = "the failure") -> str:
    return (
        f"{what}: none, one of the robot's presets (the Panda's case1, case2; see lmjx robots) or e.g. 'J2=0.3,J4=-1.5'"
    )


def _add_device(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--device",
        choices=("auto", "cpu", "gpu"),
        default="auto",
        help="where the kernels run: auto (a GPU if JAX sees one, else the CPU), cpu or gpu",
    )


def _add_planner_options(p: argparse.ArgumentParser) -> None:
    """The planner's options, shared by plan and evaluate."""
    p.add_argument(
        "--tasks",
        choices=("paper", "hard"),
        default="paper",
        help="the task set: paper (default; goal regions, distances and budget calibrated to the paper's reported "
        "outcomes, docs/EVALUATION.md) or hard (goals 22-28 cm away: tasks where choosing by simulation matters)",
    )
    p.add_argument(
        "--max-actions", type=_positive_int, help="action budget per task (default: the task set's, 30 actions)"
    )
    p.add_argument(
        "--candidates",
        type=_positive_int,
        help="greedy: actions simulated per decision (default 1024 with --sim gpu, 32 on the CPU)",
    )
    p.add_argument(
        "--asm-settings",
        choices=("lmjx", "paper"),
        default="lmjx",
        help="lmjx (default): with lmjx's refinements (edges that failed are not offered again while the "
        "target stays put, the path length around obstacles as the score, Lazy capped at 32 tries and "
        "taking its best when none helps); paper: the ASMs as the paper states them (none of these; Greedy "
        "simulates a quarter of the edges over the target)",
    )
    _add_sim(p)


def _add_sim(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--sim",
        choices=("auto", "cpu", "cpu-near", "gpu"),
        default="auto",
        help="the planner's simulator: gpu (MuJoCo Warp on a CUDA GPU, the whole scene), cpu (C MuJoCo on all "
        "host cores, the whole scene), cpu-near (C MuJoCo, only the target and its 3 nearest objects) or auto "
        "(default: gpu where a CUDA GPU and warp-lang are present, else cpu); the choice is printed on stderr "
        "and given in --json",
    )


def _add_reach_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cell", type=_positive_float, default=0.02, help="cell edge in metres (default 0.02)")
    p.add_argument(
        "--attempts",
        type=_positive_int,
        default=10,
        help="k, attempts per cell; the first half are PM (default 10)",
    )
    p.add_argument("--restarts", type=_positive_int, default=8, help="random IK restarts per attempt (default 8)")
    p.add_argument("--iterations", type=_positive_int, default=48, help="IK iterations per restart (default 48)")
    p.add_argument(
        "--ips",
        help="interaction points (the robot's ip_<name> sites) cycled by NPM attempts, comma separated (default "
        "hand,wrist,forearm; lmjx robots lists each robot's)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed; the same seed gives the same map (default 0)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="lmjx",
        description="Reach maps, kinodynamic edge bundles and planning for a robot arm with locked joints (the "
        "Franka Panda by default, the UR5e, or any arm described by an MJCF: see lmjx robots and docs/ROBOTS.md) "
        "(after Briscoe-Martinez et al., 'Exploring How Non-Prehensile Manipulation Expands Capability in "
        "Robots Experiencing Multi-Joint Failure').",
    )
    parser.add_argument(
        "--cache-dir",
        help="where compiled kernels are kept between runs (JAX's compilation cache and Warp's kernel cache); "
        "default $LMJX_CACHE_DIR, else $XDG_CACHE_HOME/lmjx or ~/.cache/lmjx; 'off' to compile every run",
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser, metavar="COMMAND")

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
    p.add_argument("--out", help="write the map to this HDF5 file (schema in maps/README.md)")
    p.add_argument("--png", help="write a heatmap (raw and smoothed) to this PNG file")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    _add_device(p)

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
        "runs again.  Every local accelerator shares the work; several hosts: the same command on each with "
        "--coordinator HOST:PORT --num-processes N --process-id I.",
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
        "--out", help="map file to write (default maps/<failure>.h5; another robot's: maps/<robot>/<failure>.h5)"
    )
    p.add_argument("--seed", type=int, default=0, help="random seed for the map and the edges (default 0)")
    p.add_argument("--cell", type=_positive_float, default=0.02, help="reach cell edge in metres (default 0.02)")
    p.add_argument(
        "--chunk",
        type=_positive_int,
        help="edges computed and saved at a time (default: by platform); not part of the result",
    )
    p.add_argument("--yes", action="store_true", help="start even when the preflight estimates more than a day of work")
    p.add_argument("--no-shard", action="store_true", help="use one device only (for comparisons)")
    p.add_argument("--coordinator", help="multi-process runs: address HOST:PORT of process 0")
    p.add_argument("--num-processes", type=_positive_int, default=1, help="multi-process runs: how many (default 1)")
    p.add_argument("--process-id", type=int, default=0, help="multi-process runs: this process's rank (default 0)")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    _add_device(p)

    p = sub.add_parser(
        "plan",
        help="one manipulation task with simulation in the loop (paper Algorithm 3)",
        description="Push the target cube of a scenario into its goal region using the edges of a map, choosing "
        "each action with an action selection mechanism (random, lazy or greedy) and executing it in a simulated "
        "'real' world whose physics differ from the planner's.",
    )
    p.add_argument("--map", required=True, help="a map file from lmjx build-map")
    p.add_argument("--scenario", required=True, type=int, choices=(1, 2, 3), help="1: clutter, 2: tunnel, 3: 11 boxes")
    p.add_argument("--asm", required=True, choices=("random", "lazy", "greedy"), help="action selection mechanism")
    p.add_argument("--failure", help="refuse the map unless it was built for this failure")
    _add_robot(p, from_map=True)
    p.add_argument("--seed", type=int, default=0, help="trial seed: layout, 'real' world, planner choices (default 0)")
    _add_planner_options(p)
    p.add_argument("--render", help="write a rendering of the trial: .png (frame strip), .gif or .mp4")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    _add_device(p)

    p = sub.add_parser(
        "evaluate",
        help="trials over failures x scenarios x ASMs, with a report",
        description="Run the paper's evaluation: for each failure, scenario and action selection mechanism, "
        "--trials tasks (the same layouts and 'real'-world perturbations for every ASM and failure).  Writes "
        "results.json after every trial (a rerun continues where it stopped), then report.md, bubble.png and "
        "actions.png.  Maps come from --maps/<failure>.h5 (lmjx build-map).",
    )
    p.add_argument("--failures", help="comma separated (default: the robot's presets; the Panda's case1,case2)")
    _add_robot(p)
    p.add_argument("--scenarios", default="1,2,3", help="comma separated (default 1,2,3)")
    p.add_argument("--asms", default="random,lazy,greedy", help="comma separated (default random,lazy,greedy)")
    p.add_argument("--trials", type=_positive_int, default=15, help="trials per cell (default 15)")
    p.add_argument("--maps", help="folder of <failure>.h5 map files (default maps; another robot's: maps/<robot>)")
    p.add_argument("--seed", type=int, default=0, help="base seed of the trials (default 0)")
    _add_planner_options(p)
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--json", action="store_true", help="print the summary table as JSON on stdout")
    _add_device(p)

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
    p.add_argument("--out", help="write every grid point's areas to this JSON file")
    p.add_argument("--png", help="write PM and NPM+PM heatmaps over the grid (two joints only)")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    _add_device(p)

    p = sub.add_parser(
        "info",
        help="what is in a map file",
        description="Validate a map file and describe its contents.",
    )
    p.add_argument("path", help="an lmjx map file (.h5)")
    _add_robot(p, from_map=True)
    p.add_argument("--json", action="store_true", help="print JSON on stdout")

    p = sub.add_parser(
        "scenarios",
        help="pictures and descriptions of the three evaluation scenarios",
        description="Print each scenario's description and write <out>/scenario<N>.png: a MuJoCo rendering of the "
        "scene (the arm at its park pose for case2, or for no failure if the robot has no case2) beside a top-down "
        "diagram of the layout; the scenarios sit where they do for the Panda, scaled to the robot's size.  "
        "Rendering needs OpenGL "
        "(on a headless machine: MUJOCO_GL=osmesa with OSMesa installed, or MUJOCO_GL=egl on a GPU); without it "
        "only the diagram is drawn.",
    )
    p.add_argument("--out", default=".", help="folder for the pictures (default: the current folder)")
    p.add_argument("--seed", type=int, default=0, help="layout seed (default 0)")
    p.add_argument("--tasks", choices=("paper", "hard"), default="paper", help="the task set (default paper)")
    _add_robot(p)

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
    p.add_argument("--out", help="HDF5 file to write (default maps/atlas.h5; another robot's: maps/<robot>/atlas.h5)")
    p.add_argument("--group", type=_positive_int, default=256, help="maps per series of launches and checkpoint (256)")
    _add_reach_options(p)
    p.add_argument("--summary", help="also write a Markdown summary here (and its figure beside it as .png)")
    # issue 20: several arms' atlases side by side (lmjx/atlas_compare.py)
    p.add_argument("--compare", action="append", metavar="ROBOT[=ATLAS]",
                   help="compute nothing but compare atlases: ROBOT a name or an MJCF, ATLAS its atlas (default "
                   "<robot's maps>/atlas.h5); repeatable; with --summary PAGE the table goes into PAGE between its "
                   "markers and the figure to img/<page>.png beside it")  # fmt: skip
    p.add_argument("--coordinator", help="multi-process runs: address HOST:PORT of process 0")
    p.add_argument("--num-processes", type=_positive_int, default=1, help="multi-process runs: how many (default 1)")
    p.add_argument("--process-id", type=int, default=0, help="multi-process runs: this process's rank (default 0)")
    p.add_argument("--no-shard", action="store_true", help="use one device only (for comparisons)")
    p.add_argument("--chunk", type=_positive_int, help="IK problems per device per launch (default by platform)")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    _add_device(p)

    p = sub.add_parser(
        "bench",
        help="benchmarks against the baselines, side by side",
        description="Time lmjx's batched IK against a serial PyBullet calculateInverseKinematics loop (PyBullet's "
        "own Panda) and pytorch_kinematics' batched IK on the same device, on the same task-plane targets; and "
        "time whole Reach-Ability maps.  Compile time is reported apart from run time.",
    )
    p.add_argument("--quick", action="store_true", help="small sizes that finish in about a minute on a CPU")
    _add_robot(p)
    p.add_argument("--sizes", help="comma-separated IK batch sizes (default: by device and --quick)")
    p.add_argument("--repeats", type=_positive_int, default=3, help="timed repetitions per figure; the median is kept")
    p.add_argument(
        "--sections",
        default="ik,maps,rollouts,planner",
        help="what to time, comma separated: ik (lmjx vs pytorch_kinematics vs PyBullet), maps (whole "
        "Reach-Ability maps), rollouts (edge rollouts vs serial C MuJoCo), planner (Greedy scoring, the GPU "
        "simulator vs C MuJoCo on all cores; needs a map with edges), agreement (the simulator's choices "
        "against C MuJoCo's over some 200 Greedy decisions; needs --maps with case1.h5 and case2.h5) "
        "(default: ik,maps,rollouts,planner)",
    )
    p.add_argument("--maps", help="agreement: folder of the robot's preset maps (default maps, or maps/<robot>)")
    p.add_argument(
        "--agreement-seeds", type=_positive_int, default=12, help="agreement: trials per failure and scenario (12)"
    )
    p.add_argument(
        "--planner-map", help="map for the planner section (default maps/case2.h5, or maps/<robot>/case2.h5)"
    )
    p.add_argument(
        "--candidates",
        help="planner section: candidate counts to score, comma separated (default 256,1024,4096 with a GPU "
        "simulator, 256 without; 8 with --quick)",
    )
    _add_sim(p)
    p.add_argument("--out", help="write the results as JSON to this file")
    p.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    _add_device(p)

    p = sub.add_parser(
        "robots",
        help="the shipped robots, their joints and failure presets",
        description="List the robots lmjx ships (use them with --robot NAME): joints, limits, interaction points and "
        "failure presets.  Any other arm: --robot PATH to an MJCF that meets docs/ROBOTS.md.",
    )
    p.add_argument("--json", action="store_true", help="print JSON on stdout")

    p = sub.add_parser(
        "robot",
        help="check a robot description (MJCF) against lmjx's contract, or import one from a URDF",
        description="lmjx robot check PATH: validate an MJCF against docs/ROBOTS.md; every missing or inconsistent "
        "part is named on a line of its own (exit status 2); a file that passes is summarised.  lmjx robot import "
        "SRC --out ARM.xml: write such an MJCF from a URDF or an MJCF with meshes.",
    )
    rsub = p.add_subparsers(dest="robot_command", required=True, parser_class=_Parser, metavar="ACTION")
    c = rsub.add_parser("check", help="validate an MJCF against docs/ROBOTS.md", description="Validate an MJCF.")
    c.add_argument("path", help="the MJCF file (.xml), or a shipped robot's name")
    c.add_argument("--json", action="store_true", help="print JSON on stdout")
    c = rsub.add_parser(
        "import",
        help="write an lmjx robot MJCF from a URDF or an MJCF with meshes",
        description="Import an arm: its links' collision geometry (meshes, primitives) is enclosed by fitted "
        "capsules, its limits are taken from the source (a missing one is named, with the flag that supplies "
        "it), the flange, tcp and interaction-point sites are placed, and the table and actuators added; the "
        "result passes lmjx robot check.  How tight the capsules are (vertices covered, volume over the "
        "geometry's convex hulls) is printed and kept in the file's header.  Method: lmjx/robot_import.py.",
    )
    c.add_argument("src", help="the URDF (.urdf) or MJCF (.xml); package:// mesh paths resolve from its folder up")
    c.add_argument("--out", required=True, help="the MJCF to write (.xml)")
    c.add_argument("--tcp", help="LINK[:x,y,z]: the grasp point, in LINK's frame (default: the last arm link, 0,0,0)")
    c.add_argument("--flange", help="LINK: the tool flange's frame (default: the last arm link's)")
    c.add_argument("--qd-max", help="velocity limit(s) [rad/s]: one value, or one per arm joint comma-separated "
                   "(default: the source's)")  # fmt: skip
    c.add_argument("--qdd-max", help="acceleration limit(s) [rad/s^2], one value or one per joint (required: "
                   "URDFs carry none)")  # fmt: skip
    c.add_argument("--tau-max", help="torque limit(s) [Nm], one value or one per joint (default: the source's effort)")
    c.add_argument("--limit", type=float, help="V: the range +-V rad of every continuous (unlimited) joint")
    c.add_argument("--ready", help="q1,...,qn: the park pose (lmjx_ready) [rad]; default: lmjx chooses one")
    c.add_argument("--ip", action="append", default=[], metavar="NAME=LINK:x,y,z[:r]",
                   help="place (or move) the interaction point ip_NAME; repeatable")  # fmt: skip
    c.add_argument("--name", help="the model's name (default lmjx_<source file's stem>)")
    # issue 20: a gripper for a bare arm, failure presets in the file
    c.add_argument("--gripper", metavar="2f85[:z]", help="attach a gripper stand-in at the flange (2f85: the "
                   "UR5e's, a Robotiq 2F-85 opened to 85 mm, tcp 0.145 m out) where the flange link's geometry "
                   "ends along its axis, or z m along it; the tcp between its fingertips (no --tcp)")  # fmt: skip
    c.add_argument("--preset", action="append", default=[], metavar="NAME=J2=0.3,J4=-1.5",
                   help="a failure preset written into the file (--failure NAME); repeatable")  # fmt: skip
    c.add_argument("--json", action="store_true", help="print JSON on stdout")
    return parser


def _set_device(choice: str, probe: bool = True) -> None:
    """Pin JAX to a platform before it initializes; fail in one line if none is there.
    Without `probe` the backend is left uninitialized (jax.distributed must come first)."""
    from .errors import LmjxError

    os.environ["JAX_PLATFORMS"] = "cpu" if choice == "cpu" else "cuda"
    if not probe:
        return
    import jax

    try:
        jax.devices()
    except RuntimeError as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise LmjxError(f"no {choice.upper()} is available to JAX ({first}); use --device auto or cpu") from None


def _reach_config(args: argparse.Namespace, robot):
    from .reach import reach_config

    ips = tuple(s.strip() for s in args.ips.split(",") if s.strip()) if args.ips is not None else robot.default_ips
    return reach_config(
        robot,
        cell=args.cell,
        attempts=args.attempts,
        restarts=args.restarts,
        iterations=args.iterations,
        interaction_points=ips,
        seed=args.seed,
    )


def _emit(args: argparse.Namespace, summary: dict, lines: Sequence[str]) -> None:
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print("\n".join(lines))


def cmd_reach(args: argparse.Namespace) -> int:
    from .failure import parse_failure
    from .fileio import check_writable

    robot = _load_robot(args)
    failure = parse_failure(args.failure, robot)
    config = _reach_config(args, robot)
    config.validate(robot)
    if args.out:
        check_writable(args.out, "map file")
    if args.png:
        check_writable(args.png, "heatmap")
    from .reach import reach_map

    result = reach_map(failure, config, robot=robot, progress=True)
    if args.out:
        from .mapfile import write_reach_map

        write_reach_map(args.out, result, robot)
    if args.png:
        from .plots import reach_heatmap

        reach_heatmap(result, args.png)
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


def cmd_lock_search(args: argparse.Namespace) -> int:
    from .errors import ConfigError
    from .failure import parse_failure
    from .fileio import check_writable, write_text_atomic
    from .locksearch import lock_grid, lock_search, parse_joints

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
        check_writable(args.out, "results file")
    if args.png:
        check_writable(args.png, "plot")
    match = None
    if args.match:
        try:
            match = tuple(float(v) for v in args.match.split(","))
        except ValueError:
            match = ()
        if len(match) != 2 or not all(0 <= v <= 2 for v in match):
            raise ConfigError(f"--match takes two ratios such as 0.7294,0.9239, got '{args.match}'")
    grids = tuple(lock_grid(robot, j, args.grid) for j in joints)
    res = lock_search(joints, grids, config, robot=robot, base=base, progress=True)
    angles, pm, npm = res.best()
    summary = {
        "joints": [f"J{j}" for j in joints],
        "base": base.spec,
        "grid": [[round(float(v), 4) for v in g] for g in grids],
        "best": {
            **{f"J{j}": round(a, 4) for j, a in zip(joints, angles, strict=True)},
            "pm_m2": pm,
            "npm_pm_m2": npm,
        },
        "points": res.rows(),
        "seconds": round(res.seconds, 3),
    }
    extra = []
    if match is not None:
        from .reach import reach_map

        ref = reach_map(parse_failure("none", robot), config, robot=robot).areas()
        m_angles, m_pm, m_npm = res.closest(match[0], match[1], ref)
        summary["match"] = {
            "ratios": list(match),
            "reference_m2": ref,
            **{f"J{j}": round(a, 4) for j, a in zip(joints, m_angles, strict=True)},
            "pm_m2": m_pm,
            "npm_pm_m2": m_npm,
        }
        m_text = ", ".join(f"J{j}={a:.4f}" for j, a in zip(joints, m_angles, strict=True))
        extra.append(
            f"closest to ratios {match[0]:g}, {match[1]:g} of no failure (PM {ref['pm']:.4f}, NPM+PM "
            f"{ref['npm_pm']:.4f} m^2): {m_text}: PM {m_pm:.4f} m^2, NPM+PM {m_npm:.4f} m^2"
        )
        angles_for_plot = m_angles
    else:
        angles_for_plot = angles
    if args.out:
        write_text_atomic(args.out, json.dumps(summary, indent=2) + "\n")
    if args.png:
        from .plots import lock_search_plot

        lock_search_plot(
            grids[0], grids[1], res.pm, res.npm_pm, (f"J{joints[0]}", f"J{joints[1]}"), angles_for_plot, args.png
        )
    width = max(len(k) for k in res.rows()[0])
    lines = ["  ".join(k.rjust(width) for k in res.rows()[0])]
    lines += ["  ".join(f"{v}".rjust(width) for v in row.values()) for row in res.rows()]
    best = ", ".join(f"J{j}={a:.4f}" for j, a in zip(joints, angles, strict=True))
    lines.append(f"best (smallest PM, then largest NPM+PM): {best}: PM {pm:.4f} m^2, NPM+PM {npm:.4f} m^2")
    lines += extra
    _emit(args, summary, lines)
    return 0


def _default_map_path(spec: str, robot) -> str:
    safe = "".join(c if c.isalnum() or c in "-." else "_" for c in spec)
    return f"{robot.maps_dir}/{safe}.h5"


def cmd_build_map(args: argparse.Namespace) -> int:
    from .bundle import BundleConfig
    from .edgestream import build_map, partial_path
    from .failure import parse_failure
    from .reach import reach_config

    if args.coordinator or args.num_processes > 1:
        if not args.coordinator:
            from .errors import ConfigError

            raise ConfigError("--num-processes > 1 needs --coordinator HOST:PORT")
        from .sharding import init_distributed

        init_distributed(args.coordinator, args.num_processes, args.process_id)
    import jax

    robot = _load_robot(args)
    failure = parse_failure(args.failure, robot)
    reach_cfg = reach_config(robot, cell=args.cell, seed=args.seed)
    bundle_cfg = BundleConfig(
        edges=args.edges, seed=args.seed, build_chunk=args.chunk, interaction_points=robot.default_ips
    )
    out = args.out or _default_map_path(failure.spec, robot)
    lead = jax.process_index() == 0
    try:
        s = build_map(
            out, failure, reach_cfg, bundle_cfg, robot, progress=True, sharded=not args.no_shard, yes=args.yes,
            say=lambda line: print(line, file=sys.stderr),
        )  # fmt: skip
    except KeyboardInterrupt:
        _leave_interrupted(
            f"lmjx build-map: interrupted; nothing was written to {out}; the chunks done are kept in "
            f"{partial_path(out)}: rerun the same command to continue"
        )
    if not lead:
        return 0
    from .mapfile import load_map

    m = load_map(out, robot, lazy=True)
    reach = m.reach
    assert reach is not None
    summary = {
        "robot": robot.key,
        "failure": failure.spec,
        "out": out,
        "seed": args.seed,
        "reach": {k: reach.summary()[k] for k in ("cell_m", "area_m2", "area_raw_m2", "seconds", "compile_seconds")},
        "edges": {k: v for k, v in s.items() if k not in ("bytes_per_state", "raw_bytes_per_state")},
        "bytes_per_state": round(s.get("bytes_per_state", 0.0), 2),
        "raw_bytes_per_state": round(s.get("raw_bytes_per_state", 0.0), 2),
        "device": s["device"],
        "devices": s["devices"],
        "processes": s["processes"],
    }
    m.close()
    rej = ", ".join(f"{k} {v}" for k, v in s["rejected"].items() if v)
    lines = [
        f"{robot.key}, failure {failure.describe()} on {s['device']} ({s['devices']} device(s), "
        f"{s['processes']} process(es)): "
        f"map written to {out}",
        f"  reach: PM {reach.areas()['pm']:.4f} m^2, NPM+PM {reach.areas()['npm_pm']:.4f} m^2 ({reach.seconds:.2f} s)",
        f"  edges: {s['edges_valid']:,} valid of {s['edges_sampled']:,} sampled; rejected: {rej or 'none'}",
        f"  rollouts: {s['edge_steps']:,} edge-steps in {s['rollout_seconds']:.2f} s "
        f"({s['edge_steps_per_s'] / 1e6:.2f} M/s); edges {s['seconds']:.2f} s + {s['compile_seconds']:.1f} s compile "
        f"(of which writing the map alongside {s['write_seconds']:.1f} s, its index {s['finish_seconds']:.1f} s)",
        f"  storage: {summary['bytes_per_state']:.1f} bytes per stored state "
        f"({summary['raw_bytes_per_state']:.0f} uncompressed)",
    ]
    _emit(args, summary, lines)
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    from .mapfile import load_map

    robot = _load_robot(args) if args.robot else None  # None: the robot the map names
    m = load_map(args.path, robot, lazy=True)  # the states stay in the file: a map of any size answers at once
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
            f"  reach map: {len(r.xs)} x {len(r.ys)} cells of {r.config.cell * 100:g} cm, seed {r.config.seed}",
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
    _emit(args, info, lines)
    return 0


def _resolve_sim(args: argparse.Namespace) -> tuple[str, str]:
    """The planner's simulator for --sim, announced on stderr."""
    from .trial import resolve_simulator

    name, why = resolve_simulator(args.sim)
    print(f"lmjx {args.command}: simulator {name} ({why})", file=sys.stderr)
    return name, why


def _planner_config(args: argparse.Namespace, asm: str, sim: str):
    from .planner import PlannerConfig
    from .trial import DEFAULT_CANDIDATES

    config = PlannerConfig(
        asm=asm, max_actions=args.max_actions, greedy_candidates=args.candidates or DEFAULT_CANDIDATES[sim]
    )
    return config.paper() if args.asm_settings == "paper" else config


def cmd_plan(args: argparse.Namespace) -> int:
    from .errors import ConfigError
    from .failure import parse_failure
    from .fileio import check_writable
    from .mapfile import load_map
    from .trial import make_simulator, run_trial, setup_trial

    m = load_map(args.map, _load_robot(args) if args.robot else None)  # None: the robot the map names
    robot = m.robot
    assert robot is not None
    if args.failure is not None and parse_failure(args.failure, robot).locked != m.failure.locked:
        raise ConfigError(f"{args.map} holds a map of failure {m.failure.spec}, not {args.failure}")
    if m.edges is None:
        raise ConfigError(f"{args.map} has no edges; build it with: lmjx build-map --failure {m.failure.spec}")
    if args.render:
        from .render import check_render_path

        check_render_path(args.render)
        check_writable(args.render, "rendering")
    sim_name, why = _resolve_sim(args) if args.asm != "random" else ("none", "random does not simulate")
    config = _planner_config(args, args.asm, sim_name if sim_name != "none" else "cpu")
    sim = make_simulator(robot, args.scenario, sim_name, args.tasks) if sim_name != "none" else None
    setup = setup_trial(robot, m, args.scenario, config, args.seed, simulator=sim, tasks=args.tasks)
    recorder = None
    if args.render:
        from .render import Recorder

        recorder = Recorder(setup.world)
    res = run_trial(setup)
    if recorder is not None:
        recorder.write(args.render)
    summary = {
        "robot": robot.key,
        "failure": m.failure.spec,
        "tasks": args.tasks,
        "scenario": args.scenario,
        "asm": args.asm,
        "seed": args.seed,
        "simulator": sim_name,
        "simulator_reason": why,
        "simulator_description": sim.description if sim is not None else None,
        "candidates": config.greedy_candidates if args.asm == "greedy" else None,
        "asm_settings": config.settings(),
        **res.summary(),
        "steps": [s.summary() for s in res.steps],
    }
    lines = [
        f"failure {m.failure.spec}, scenario {args.scenario} ({args.tasks} tasks), {args.asm}, seed {args.seed}: "
        f"{'success' if res.success else 'failure'} ({res.reason}) after {res.actions} actions",
        f"  planning {res.planning_s:.1f} s, execution {res.execution_s:.1f} s, "
        f"target {res.final_distance * 100:.1f} cm from the goal's centre",
    ]
    if sim is not None:
        lines.append(f"  simulator: {sim.description}")
    if args.render:
        lines.append(f"  rendering written to {args.render}")
    _emit(args, summary, lines)
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .errors import ConfigError
    from .evaluate import EvalConfig, evaluate, load_maps, plots, report_markdown, simulator_description, summarize
    from .fileio import check_writable, write_text_atomic

    def split(text: str, cast=str):
        try:
            return tuple(cast(x.strip()) for x in text.split(",") if x.strip())
        except ValueError:
            raise ConfigError(f"cannot read the list '{text}'") from None

    from dataclasses import replace

    robot = _load_robot(args)
    failures = split(args.failures) if args.failures else tuple(robot.profile.presets)
    if not failures:
        raise ConfigError(f"the robot {robot.key} has no failure presets: give --failures (e.g. none)")
    config = EvalConfig(
        failures=failures,
        scenarios=split(args.scenarios, int),
        asms=split(args.asms),
        trials=args.trials,
        seed=args.seed,
        tasks=args.tasks,
    )
    config.validate()
    out = Path(args.out)
    check_writable(out / "results.json", "results")
    maps = load_maps(robot, config.failures, Path(args.maps or robot.maps_dir))
    simulates = bool(set(config.asms) - {"random"})
    sim_name, why = _resolve_sim(args) if simulates else ("cpu", "random does not simulate")
    config = replace(config, planner=_planner_config(args, "greedy", sim_name), backend=sim_name)
    records = evaluate(robot, maps, config, out)
    write_text_atomic(out / "report.md", report_markdown(records, config, simulator_description(sim_name), robot))
    plots(records, out)
    rows = summarize(records)
    lines = [
        f"{len(records)} trials ({config.tasks} tasks); results in {out}/results.json, report in {out}/report.md",
        f"  simulator {sim_name} ({why}), greedy {config.planner.greedy_candidates} candidates",
    ]
    lines += [
        f"  {r['failure']} scenario {r['scenario']} {r['asm']:>6}: {r['success_rate'] * 100:5.1f} % of {r['trials']}, "
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


def cmd_scenarios(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .actions import park_pose
    from .failure import parse_failure
    from .fileio import check_writable
    from .render import gl_problem
    from .scenario_figure import scenario_picture
    from .scenarios import SCENARIOS, sample_layout, scenario

    out = Path(args.out)
    check_writable(out / "scenario1.png", "pictures")
    robot = _load_robot(args)
    problem = gl_problem()
    if problem is not None:
        print(f"note: drawing the diagrams only: {problem}", file=sys.stderr)
    q = park_pose(robot, parse_failure("case2" if "case2" in robot.profile.presets else "none", robot))
    for n in sorted(SCENARIOS):
        sc = scenario(n, robot.profile.task_scale, args.tasks)
        path = out / f"scenario{n}.png"
        scenario_picture(robot, sc, sample_layout(sc, args.seed), q, path, with_render=problem is None)
        head = f"scenario {n} ({args.tasks} tasks, {sc.budget} actions): {sc.title}"
        print(f"{head}\n  {sc.description}\n  picture: {path}")
    return 0


def cmd_atlas(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from .errors import ConfigError

    if args.compare:  # issue 20: compare atlases, compute none
        from .atlas_compare import compare_report

        _emit(args, *compare_report(args.compare, args.summary))
        return 0

    try:
        sizes = tuple(int(x) for x in args.joints.split(",") if x.strip())
    except ValueError:
        raise ConfigError(f"--joints must be numbers of locked joints like 2,3, got '{args.joints}'") from None
    if args.coordinator or args.num_processes > 1:
        if not args.coordinator:
            raise ConfigError("--num-processes > 1 needs --coordinator HOST:PORT")
        from .sharding import init_distributed

        init_distributed(args.coordinator, args.num_processes, args.process_id)
    import jax

    from .atlas import AtlasConfig, build_atlas, expected_maps

    robot = _load_robot(args)
    out = args.out or f"{robot.maps_dir}/atlas.h5"
    reach = replace(_reach_config(args, robot), chunk=args.chunk)
    config = AtlasConfig(sizes=sizes, angles=args.angles, seed=args.seed, group=args.group, reach=reach)
    config.validate(robot)
    lead = jax.process_index() == 0
    if args.summary and lead:
        from .fileio import check_writable

        check_writable(args.summary, "summary")
    try:
        st = build_atlas(robot, config, out, progress=True, sharded=not args.no_shard)
    except KeyboardInterrupt:
        _leave_interrupted(
            f"lmjx atlas: interrupted; finished groups are kept in {out}.partial: rerun the same command to continue"
        )
    if not lead:
        return 0
    if args.summary:
        from pathlib import Path

        from .atlas_report import write_summary

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


def cmd_robots(args: argparse.Namespace) -> int:
    from .robot import ROBOTS, load_robot

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


def cmd_robot_import(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .errors import ConfigError
    from .fileio import check_writable
    from .robot import check_robot
    from .robot_import import ImportOptions, command_line, import_robot

    out = Path(args.out)
    if out.suffix.lower() != ".xml":
        raise ConfigError(f"--out {out}: an MJCF is written to a .xml file")
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


def cmd_robot(args: argparse.Namespace) -> int:
    from .robot import check_robot, load_robot, resolve_robot

    if args.robot_command == "import":
        return cmd_robot_import(args)
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


def cmd_bench(args: argparse.Namespace) -> int:
    from .bench import run_bench

    return run_bench(args)


COMMANDS = {
    "build-map": cmd_build_map,
    "plan": cmd_plan,
    "evaluate": cmd_evaluate,
    "reach": cmd_reach,
    "lock-search": cmd_lock_search,
    "info": cmd_info,
    "bench": cmd_bench,
    "atlas": cmd_atlas,
    "scenarios": cmd_scenarios,
    "robots": cmd_robots,
    "robot": cmd_robot,
}


def threading_main() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def _leave_interrupted(message: str) -> NoReturn:
    """Say what an interrupt left behind, then leave at once: XLA's worker threads may still
    be running the interrupted kernel, and tearing the interpreter down under them can crash.
    Output files are written atomically, so there is nothing left to clean up."""
    print(message, file=sys.stderr)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(EXIT_INTERRUPTED)


def _on_sigint(signum: int, frame: object) -> None:
    """Ctrl-C: unwind normally (temporary files are removed on the way out), and if anything
    swallows the interrupt, leave anyway a few seconds later."""

    def leave() -> None:
        print("lmjx: interrupted", file=sys.stderr)
        sys.stderr.flush()
        os._exit(EXIT_INTERRUPTED)

    import threading

    timer = threading.Timer(10.0, leave)
    timer.daemon = True
    timer.start()
    raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    from .hostmem import return_large_buffers

    return_large_buffers()
    parser = build_parser()
    args = parser.parse_args(argv)
    import signal

    from .errors import LmjxError

    if threading_main():
        signal.signal(signal.SIGINT, _on_sigint)
    from .cache import configure

    configure(args.cache_dir)
    if args.command in ("plan", "evaluate", "bench"):
        # JAX and MuJoCo Warp share the GPU there: JAX must not take most of its memory up front
        os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

    try:
        if getattr(args, "device", "auto") != "auto":
            _set_device(args.device, probe=not getattr(args, "coordinator", None))
        return COMMANDS[args.command](args)
    except LmjxError as e:
        print(f"lmjx {args.command}: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        _leave_interrupted(f"lmjx {args.command}: interrupted; no output was written")


if __name__ == "__main__":
    sys.exit(main())
