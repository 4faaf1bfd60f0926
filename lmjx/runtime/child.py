"""lmjx's own child processes (a build's map writer, its peers on other GPUs): a clean
interpreter importing lmjx from where this one was, in a process group of its own (Ctrl-C
reaches only the parent, which stops it), with a pipe each way; and its errors as the parent
raises them."""

from __future__ import annotations

import os
import subprocess
import sys
from multiprocessing.connection import Connection
from pathlib import Path

from lmjx.errors import LmjxError

# The child's program: lmjx from the parent's folder (then off the path again, so that it
# shadows nothing), its entry point called with its pipes' descriptors from the command line.
_START = (
    "import sys; sys.path.insert(0, sys.argv[1]); import lmjx; sys.path.pop(0); import {module} as m; "
    "m.{function}(int(sys.argv[2]), int(sys.argv[3]))"
)


def start_child(module: str, function: str, env: dict[str, str]) -> tuple[subprocess.Popen, Connection, Connection]:
    """Start `module.function(inbox_fd, outbox_fd)` in a child process with environment
    `env`: (the process, the pipe to it, the pipe from it)."""
    r_in, w_in = os.pipe()
    r_out, w_out = os.pipe()
    here = str(Path(__file__).resolve().parents[2])
    program = _START.format(module=module, function=function)
    try:
        proc = subprocess.Popen([sys.executable, "-c", program, here, str(r_in), str(w_out)],
                                pass_fds=(r_in, w_out), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                env=env, start_new_session=True)  # fmt: skip
    except BaseException:
        for fd in (w_in, r_out):
            os.close(fd)
        raise
    finally:
        os.close(r_in)
        os.close(w_out)
    return proc, Connection(w_in, readable=False), Connection(r_out, writable=False)


def annotated(e: BaseException, trace: str, where: str) -> BaseException:
    """A child's exception, with its traceback there as a note saying `where` it ran (but
    for a user's error, whose message says it all)."""
    if not isinstance(e, LmjxError):
        e.add_note(f"in {where}:\n{trace}")
    return e
