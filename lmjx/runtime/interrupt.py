"""Ctrl-C in the Python API: the call ends with a KeyboardInterrupt of its own, raised once
everything the interrupted work held is let go.

An interrupt that lands in JAX's tracing, XLA's compiling or a device's computing leaves the
work's frames (and the half-made programs and device buffers they hold) alive in the
exception's traceback until the interpreter ends; torn down then, after JAX's backends, they
crashed the process (a segmentation fault or an abort in PyGILState_Release, measured: every
time for an interrupt 3 s into a first reach map).  `interruptible` drops that traceback,
collects what it held while JAX is whole, and raises a fresh KeyboardInterrupt from the
public function.
"""

from __future__ import annotations

import functools
import gc
from collections.abc import Callable
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])


def interruptible(fn: F) -> F:
    """`fn`, ending with a clean KeyboardInterrupt on Ctrl-C (see the module docstring)."""

    @functools.wraps(fn)
    def call(*args: Any, **kwargs: Any) -> Any:
        interrupted = False
        try:
            return fn(*args, **kwargs)
        except KeyboardInterrupt:
            interrupted = True  # (the traceback and its frames go with this block)
        if interrupted:
            gc.collect()
            raise KeyboardInterrupt
        return None  # (not reached)

    return call  # type: ignore[return-value]
