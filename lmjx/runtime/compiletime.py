"""Seconds this process has spent compiling, so that a decision's planning time can leave
them out.

A trial's first decision on a fresh machine compiles what it runs: lmjx's JAX kernels
(lowering and XLA's compilation: JAX's monitoring events, counted here per thread; not
tracing, which JAX before 0.10 reports again for every nested jit, and which takes a few
per cent of a kernel's compilation) and the
GPU simulator's CUDA graphs with MuJoCo Warp's kernels (its `capture_seconds`, read with
`simulator_compile_seconds`).  On the GPU this took 173-175 s of a first decision
(benchmarks/RESULTS.md); charged to the trial that made it, it would count against its
planning limit.  Compilation is not planning: `Planner` subtracts what was compiled while
it computed or simulated from the decision's planning time and records it apart
(`StepRecord.compile_s`).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

# JAX's duration events of lowering a program and compiling it (each reported once, on the
# thread that compiled)
COMPILE_EVENTS = ("/jax/core/compile/jaxpr_to_mlir_module_duration", "/jax/core/compile/backend_compile_duration")

_lock = threading.Lock()
_seconds: dict[int, float] = {}  # thread -> seconds it spent compiling
_listening = False


def _heard(event: str, duration: float, **_: Any) -> None:
    if event in COMPILE_EVENTS:
        me = threading.get_ident()
        with _lock:
            _seconds[me] = _seconds.get(me, 0.0) + float(duration)


def jax_compile_seconds() -> float:
    """Seconds JAX has spent lowering and compiling on the calling thread since the first
    call (which starts listening; a JAX without monitoring events reports 0).  Per thread:
    a decision is not charged with what another thread compiled meanwhile (the test suite
    compiles kernels ahead in a thread of its own)."""
    global _listening
    if not _listening:
        with _lock:
            if not _listening:
                try:
                    import jax.monitoring

                    jax.monitoring.register_event_duration_secs_listener(_heard)
                except (ImportError, AttributeError):
                    pass
                _listening = True
    return _seconds.get(threading.get_ident(), 0.0)


def simulator_compile_seconds(sim: Any) -> float:
    """Seconds `sim` has spent capturing its graphs and compiling its kernels (0 for a
    simulator that compiles nothing: C MuJoCo)."""
    return float(getattr(sim, "capture_seconds", 0.0) or 0.0)


def compile_seconds(sim: Any = None) -> float:
    """JAX's compilation seconds so far, plus `sim`'s."""
    return jax_compile_seconds() + simulator_compile_seconds(sim)


_SPANS: list[tuple[float, float]] = []  # (start, end) of every compilation, perf_counter seconds


@contextlib.contextmanager
def compile_span() -> Iterator[None]:
    """Record the block's wall-clock span as compiling (`compile_wall_seconds`)."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        with _lock:
            _SPANS.append((t0, time.perf_counter()))


def compile_wall_seconds(since: float, until: float | None = None) -> float:
    """The wall-clock seconds between `since` and `until` (default: now) during which at
    least one compilation ran: programs compiled side by side on threads count once, so the
    figure never exceeds the wall time (their seconds summed can)."""
    until = time.perf_counter() if until is None else until
    with _lock:
        spans = sorted((max(a, since), min(b, until)) for a, b in _SPANS if b > since and a < until)
    total, end = 0.0, since
    for a, b in spans:
        if b > end:
            total += b - max(a, end)
            end = b
    return total


_TOLD: list[Callable[[str, float], None]] = []
TELL_FROM = 1.0  # [s] a compilation this long or longer is told (`telling_compiled`); loads from the cache are not


@contextlib.contextmanager
def telling_compiled(note: Callable[[str, float], None]) -> Iterator[None]:
    """Within: `note(program, seconds)` is told of every program compiled (`told_compiled`),
    so that a long first build shows its compiling as it goes."""
    _TOLD.append(note)
    try:
        yield
    finally:
        _TOLD.remove(note)


def told_compiled(program: str, seconds: float) -> None:
    """A program was compiled in `seconds`: told to those listening (`telling_compiled`)."""
    if seconds >= TELL_FROM:
        for note in list(_TOLD):
            note(program, seconds)
