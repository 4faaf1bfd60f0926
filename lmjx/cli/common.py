"""What the commands share: the parser class with one-line errors, argument types and
option groups, --device and --robot, output-path checks by file extension, JSON or text
output, and leaving on an interrupt.  Nothing here runs a command."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

if TYPE_CHECKING:
    from lmjx.model.robot import Robot
    from lmjx.reach.reachability import ReachConfig

# Exit statuses (docs/DETAILS.md, "Exit status"): 0 done; 1 `info --verify` found a damaged
# map; 2 bad input (one line on stderr, nothing written); 3 `plan --strict`: the task failed;
# 130 interrupted.
EXIT_DAMAGED = 1
EXIT_USAGE = 2
EXIT_TASK_FAILED = 3
EXIT_INTERRUPTED = 130

# What matplotlib writes, by file extension (the format follows the extension).
FIGURE_FORMATS = ("png", "jpg", "jpeg", "pdf", "svg", "svgz", "eps", "ps", "tif", "tiff", "webp")
HDF5_SUFFIXES = (".h5", ".hdf5")


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


INT_MAX = 2**31 - 1  # the largest count any option takes (counts are held in 32-bit integers)


def _whole_number(text: str, low: int, high: int = INT_MAX) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
    if v < low:
        raise argparse.ArgumentTypeError(f"must be at least {low}, got {text}")
    if v > high:
        raise argparse.ArgumentTypeError(f"must be at most {high}, got {text}")
    return v


def _positive_int(text: str) -> int:
    return _whole_number(text, 1)


def _nonnegative_int(text: str) -> int:
    return _whole_number(text, 0)


def _seed(text: str) -> int:
    """A seed: a whole number from 0 to `lmjx.checks.SEED_MAX`."""
    from lmjx.checks import SEED_MAX

    return _whole_number(text, 0, SEED_MAX)


def _positive_ints(text: str) -> tuple[int, ...]:
    """A comma-separated list of whole numbers, each at least 1 (at least one of them)."""
    values = tuple(_positive_int(x.strip()) for x in text.split(",") if x.strip())
    if not values:
        raise argparse.ArgumentTypeError(f"give whole numbers separated by commas, got '{text}'")
    return values


SEED_RANGE = "0 to 4294967295"  # (lmjx.checks.SEED_MAX)
SEED_HELP = f"random seed, {SEED_RANGE}"
OVERWRITE_RULE = (
    "lmjx never replaces a map file (or a robot's MJCF) already at --out unless --overwrite is given; pictures, "
    "reports and JSON results it writes over"
)


def _add_overwrite(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--overwrite", action="store_true", help=f"replace {what} already at --out ({OVERWRITE_RULE})")


def check_not_there(path: str | Path, overwrite: bool, what: str) -> None:
    """Refuse, in one line naming --overwrite, to write over a file a user may want to keep."""
    from lmjx.errors import OutputPathError

    p = Path(path)
    if p.exists() and not p.is_dir() and not overwrite:
        raise OutputPathError(f"--out {p} already exists; add --overwrite to replace it with the new {what}, or "
                              "choose another --out")  # fmt: skip


CACHE_DIR_HELP = (
    "where compiled kernels are kept between runs (JAX's compilation cache and Warp's kernel cache); "
    "default $LMJX_CACHE_DIR, else $XDG_CACHE_HOME/lmjx or ~/.cache/lmjx; 'off' to compile every run; "
    "an unwritable folder is warned about and the run goes on without it"
)


def add_global_options(p: argparse.ArgumentParser, top: bool) -> None:
    """--cache-dir, accepted before the command (`top`) and after it: after it, it is only
    set when given, so that it does not undo one given before."""
    extra = {} if top else {"default": argparse.SUPPRESS}
    p.add_argument("--cache-dir", help=CACHE_DIR_HELP if top else "as before the command (lmjx --help)", **extra)


def _add_robot(p: argparse.ArgumentParser, from_map: bool = False) -> None:
    default = "the robot the map was built for" if from_map else "panda"
    p.add_argument(
        "--robot",
        metavar="NAME|PATH",
        help=f"a shipped arm (lmjx robots) or an MJCF's path (default: {default})",
    )


def _load_robot(args: argparse.Namespace) -> Robot:
    """The robot --robot names (the Panda when it is not given)."""
    from lmjx.model.robot import load_robot

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
        help="where the kernels run: auto (default: a GPU if JAX sees one), cpu or gpu",
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
    p.add_argument("--seed", type=_seed, default=0, help=f"{SEED_HELP}; the same seed gives the same map (default 0)")


def _add_distributed(p: argparse.ArgumentParser) -> None:
    p.add_argument("--coordinator", help="multi-process runs: address HOST:PORT of process 0")
    p.add_argument("--num-processes", type=_positive_int, default=1, help="multi-process runs: how many (default 1)")
    p.add_argument(
        "--process-id", type=_nonnegative_int, default=0, help="multi-process runs: this process's rank (default 0)"
    )


def _init_distributed(args: argparse.Namespace) -> None:
    """jax.distributed for --coordinator/--num-processes, before JAX starts."""
    from lmjx.errors import ConfigError

    if args.process_id >= args.num_processes:
        raise ConfigError(f"--process-id {args.process_id}: ranks are 0 to {args.num_processes - 1} (--num-processes)")
    if args.coordinator or args.num_processes > 1:
        if not args.coordinator:
            raise ConfigError("--num-processes > 1 needs --coordinator HOST:PORT")
        from lmjx.runtime.sharding import init_distributed

        init_distributed(args.coordinator, args.num_processes, args.process_id)


def _set_device(choice: str, probe: bool = True) -> None:
    """Pin JAX to a platform before it initializes; fail in one line if none is there.
    Without `probe` the backend is left uninitialized (jax.distributed must come first)."""
    from lmjx.errors import LmjxError

    before = os.environ.get("JAX_PLATFORMS")
    os.environ["JAX_PLATFORMS"] = "cpu" if choice == "cpu" else "cuda"
    if not probe:
        return
    import jax

    try:
        platforms = sorted({d.platform for d in jax.devices()})
        want = {"cpu"} if choice == "cpu" else {"gpu", "cuda"}
        problem = None if want & set(platforms) else f"JAX already runs on {', '.join(platforms)}"
    except (RuntimeError, AssertionError) as e:  # no backend at all for the platform: AssertionError
        text = str(e).strip()
        problem = text.splitlines()[0] if text else "no CUDA backend is installed"
    if problem is not None:
        if before is None:
            os.environ.pop("JAX_PLATFORMS", None)
        else:
            os.environ["JAX_PLATFORMS"] = before
        raise LmjxError(f"no {choice.upper()} is available to JAX ({problem}); use --device auto or cpu") from None


def _reach_config(args: argparse.Namespace, robot: Robot) -> ReachConfig:
    from lmjx.reach.reachability import reach_config

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


def figure_format(path: str | Path, option: str) -> str:
    """The image format a figure option's file name asks for (its extension), or a one-line refusal."""
    from lmjx.errors import ConfigError

    ext = Path(path).suffix.lower().lstrip(".")
    if ext not in FIGURE_FORMATS:
        given = f"'.{ext}'" if ext else "no extension"
        raise ConfigError(
            f"{option} {path}: cannot write a figure with {given}; end the name in one of "
            + ", ".join(f".{f}" for f in FIGURE_FORMATS)
        )
    return ext


def check_suffix(path: str | Path, option: str, suffixes: Sequence[str], what: str) -> None:
    """Refuse an output file whose extension names another format than the one written."""
    from lmjx.errors import ConfigError

    if Path(path).is_dir():
        return  # the path check says what is wrong with that
    if Path(path).suffix.lower() not in suffixes:
        raise ConfigError(f"{option} {path}: {what}; give a name ending in {' or '.join(suffixes)}")


def _emit(args: argparse.Namespace, summary: dict, lines: Sequence[str]) -> None:
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print("\n".join(lines))


def warn(command: str, message: str) -> None:
    """One line on stderr."""
    print(f"lmjx {command}: warning: {message}", file=sys.stderr)


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
