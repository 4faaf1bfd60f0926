"""The `lmjx` command line: a package of small commands.

Each module holds one command (or group) with its parser beside its function; `main` parses,
sets up what every command shares (the compile cache, the device, OpenGL only where something
is drawn) and dispatches.  User mistakes end here, in one place, with a one-line error and
exit status 2, an interrupt with status 130; neither leaves a partial output file.  Heavy
imports (JAX, MuJoCo) happen only once a command runs, so --help is instant and --device can
still choose the platform.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from collections.abc import Sequence

from lmjx import __version__
from lmjx.cli import atlas, bench, buildmap, evaluate, info, locksearch, plan, reach, robots, scenarios, view
from lmjx.cli.common import (
    EXIT_INTERRUPTED,
    EXIT_USAGE,
    _leave_interrupted,
    _on_sigint,
    _Parser,
    _set_device,
    add_global_options,
    threading_main,
    warn,
)

__all__ = ["EXIT_INTERRUPTED", "EXIT_USAGE", "build_parser", "main", "threading_main"]

# In the order of `lmjx --help`.
MODULES = (reach, buildmap, plan, evaluate, locksearch, info, scenarios, atlas, bench, robots, view)

EPILOG = """\
progress: long work (reach, build-map, lock-search, evaluate, atlas) shows a progress bar on a
terminal, and a progress line every few seconds when stderr is a file or a pipe; set
LMJX_PROGRESS=0 to turn progress off, LMJX_PROGRESS=1 for the bar even when not on a terminal.
Results go to stdout (--json for JSON), everything else to stderr.
"""

# The OpenGL library MuJoCo loads for each MUJOCO_GL (through PyOpenGL) when it is imported.
GL_LIBRARIES = {"osmesa": "OSMesa", "egl": "EGL"}
GL_FIX = {
    "osmesa": "install OSMesa (Debian: apt install libosmesa6)",
    "egl": "install EGL (a GPU driver's libEGL, or Mesa's: apt install libegl1 libegl-mesa0)",
}


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="lmjx",
        description="Reach maps, kinodynamic edge bundles and planning for a robot arm with locked joints (the "
        "Franka Panda by default, the UR5e, or any arm described by an MJCF: see lmjx robots and docs/ROBOTS.md) "
        "(after Briscoe-Martinez et al., 'Exploring How Non-Prehensile Manipulation Expands Capability in "
        "Robots Experiencing Multi-Joint Failure').",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"lmjx {__version__}")
    add_global_options(parser, top=True)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser, metavar="COMMAND")
    for module in MODULES:
        made = module.add_parser(sub)
        for p in made if isinstance(made, list) else [made]:
            add_global_options(p, top=False)
    return parser


def _draws(args: argparse.Namespace) -> bool:
    """Whether the command draws with MuJoCo's renderer (OpenGL)."""
    return args.command == "scenarios" or bool(getattr(args, "render", None))


def _gl_missing() -> str | None:
    """Before MuJoCo is imported: a one-line reason when MUJOCO_GL names an OpenGL that is not
    installed (`import mujoco` itself would fail), else None."""
    gl = os.environ.get("MUJOCO_GL", "").strip().lower()
    if gl not in GL_LIBRARIES or "mujoco" in sys.modules:
        return None
    import ctypes
    import ctypes.util
    import importlib.util

    if importlib.util.find_spec("OpenGL") is None:
        return f"MUJOCO_GL={gl} needs PyOpenGL, which is not installed (pip install PyOpenGL)"
    name = GL_LIBRARIES[gl]
    for candidate in (ctypes.util.find_library(name), f"lib{name}.so"):
        if candidate:
            try:
                ctypes.CDLL(candidate)
                return None
            except OSError:
                pass
    return f"MUJOCO_GL={gl} but lib{name} is not installed: {GL_FIX[gl]}, or unset MUJOCO_GL"


def _cache(args: argparse.Namespace) -> None:
    from lmjx.runtime.cache import configure

    configure(args.cache_dir, warn=lambda m: warn(args.command, m))


# The commands that, once done, leave without tearing the interpreter down (`entry`), and
# whether the command `main` last ran was one, run to its end in one process.
LEAVE_AT_ONCE = frozenset({"build-map"})
leave_at_once = False


def entry() -> None:
    """The `lmjx` program: `main`, then the process's exit.  A command of `LEAVE_AT_ONCE`
    that succeeded in one process leaves at once, its output flushed: everything it writes is closed and
    renamed into place by then, and its own processes and threads have ended, while tearing
    down JAX's GPU client (its programs, memory and streams) and the interpreter takes
    about 0.6 s of a 100,000-edge build's 8 s on an H200 (benchmarks/RESULTS.md)."""
    code = main()
    if leave_at_once:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(BrokenPipeError, ValueError):  # a reader that left, a stream closed
                stream.flush()
        os._exit(0)
    sys.exit(code)


def main(argv: Sequence[str] | None = None) -> int:
    from lmjx.runtime.hostmem import return_large_buffers

    return_large_buffers()
    parser = build_parser()
    args = parser.parse_args(argv)
    import shlex
    import signal

    # the command as given, for what records it (`lmjx evaluate`'s provenance)
    args.command_line = shlex.join(["lmjx", *(sys.argv[1:] if argv is None else map(str, argv))])

    from lmjx.errors import LmjxError

    if threading_main():
        signal.signal(signal.SIGINT, _on_sigint)
    _cache(args)
    # JAX takes GPU memory as its programs need it, not most of the GPU up front: taking
    # 75 % of an H200's memory at the first transfer costs seconds of every command's
    # start (benchmarks/RESULTS.md), and JAX and MuJoCo Warp share the GPU in plan,
    # evaluate and bench.  A value the user set is kept.
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

    try:
        gl = _gl_missing()
        if gl is not None:
            if _draws(args) and args.command != "scenarios":
                raise LmjxError(f"--render: {gl}")
            os.environ.pop("MUJOCO_GL")  # nothing here needs it: MuJoCo imports without OpenGL
            scenarios.gl_note = gl
        if getattr(args, "device", "auto") != "auto":
            _set_device(args.device, probe=not getattr(args, "coordinator", None))
        code = args.run(args)
        global leave_at_once
        # (several processes leave together: jax.distributed's shutdown at exit)
        leave_at_once = code == 0 and args.command in LEAVE_AT_ONCE and not getattr(args, "coordinator", None)
        return code
    except LmjxError as e:
        print(f"lmjx {args.command}: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        _leave_interrupted(f"lmjx {args.command}: interrupted; no output was written")
    except BrokenPipeError:  # stdout closed early (`lmjx robots | head`): not an error of ours
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
