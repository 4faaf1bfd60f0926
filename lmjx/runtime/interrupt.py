"""Ctrl-C in the Python API: the call ends with a KeyboardInterrupt of its own, raised once
everything the interrupted work held is let go.

An interrupt that lands in JAX's tracing, XLA's compiling or a device's computing leaves the
work's frames (and the half-made programs and device buffers they hold) alive in the
exception's traceback until the interpreter ends; torn down then, after JAX's backends, they
crashed the process (a segmentation fault or an abort in PyGILState_Release, measured: every
time for an interrupt 3 s into a first reach map).  `interruptible` drops that traceback,
collects what it held while JAX is whole, and raises a fresh KeyboardInterrupt from the
public function.  An interrupt while XLA compiles can still leave XLA's own state half-made
(measured: a segmentation fault in the teardown in 4 of 5 interrupts 3 s into a first reach
map with an empty compile cache), so where that KeyboardInterrupt ends the program (the
interpreter printed it: `sys.last_value`), the program leaves by SIGINT as Python would, once
the interpreter's exit handlers registered after the interrupt have run and the standard
streams are flushed, without the teardown.  A program that catches the KeyboardInterrupt
and goes on is left alone.  An interrupt that lands in a callback Python cannot raise from (JAX's
garbage collector callback: Python prints it and goes on, and the work ran to its end) is
raised again at once (`_keep_interrupts_raised_in_callbacks`).
"""

from __future__ import annotations

import _thread
import atexit
import contextlib
import functools
import gc
import os
import signal
import sys
from collections.abc import Callable
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])


def interruptible(fn: F) -> F:
    """`fn`, ending with a clean KeyboardInterrupt on Ctrl-C (see the module docstring)."""

    @functools.wraps(fn)
    def call(*args: Any, **kwargs: Any) -> Any:
        interrupted = False
        _keep_interrupts_raised_in_callbacks()
        try:
            return fn(*args, **kwargs)
        except KeyboardInterrupt:
            interrupted = True  # (the traceback and its frames go with this block)
        if interrupted:
            gc.collect()
            _leave_by_sigint_if_it_ends_the_program()
            raise KeyboardInterrupt
        return None  # (not reached)

    return call  # type: ignore[return-value]


_registered: list[bool] = []


def _leave_by_sigint_if_it_ends_the_program() -> None:
    """At the interpreter's exit, where an uncaught KeyboardInterrupt ends it: flush the
    standard streams and end by SIGINT (exit status -2, 130 in a shell), as Python itself
    does after such an interrupt, skipping the teardown of the extension modules."""
    if _registered:
        return
    _registered.append(True)

    def leave() -> None:
        if not isinstance(getattr(sys, "last_value", None), KeyboardInterrupt):
            return
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError, AttributeError):
                stream.flush()
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGINT)

    atexit.register(leave)


def _keep_interrupts_raised_in_callbacks() -> None:
    """Once per process: a KeyboardInterrupt that Python could not raise (it landed in a
    garbage collector callback or a finalizer) is delivered again as SIGINT, so that it
    interrupts the work instead of being printed and lost; anything else goes to the hook
    there was."""
    if getattr(sys.unraisablehook, "_lmjx", False):
        return
    before = sys.unraisablehook

    def hook(unraisable: Any) -> None:
        if isinstance(unraisable.exc_value, KeyboardInterrupt):
            _thread.interrupt_main()  # (pending: raised once the callback has returned)
            return
        before(unraisable)

    hook._lmjx = True  # type: ignore[attr-defined]
    sys.unraisablehook = hook
