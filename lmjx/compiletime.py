"""Seconds this process has spent compiling, so that a decision's planning time can leave
them out.

A trial's first decision on a fresh machine compiles what it runs: lmjx's JAX kernels
(tracing, lowering and XLA's compilation: JAX's monitoring events, counted here) and the
GPU simulator's CUDA graphs with MuJoCo Warp's kernels (its `capture_seconds`, read with
`simulator_compile_seconds`).  On the GPU this took 173-175 s of a first decision
(docs/EVALUATION.md), charged until then to the trial that made it and counted against its
planning limit.  Compilation is not planning: `Planner` subtracts what was compiled while
it computed or simulated from the decision's planning time and records it apart
(`StepRecord.compile_s`).
"""

from __future__ import annotations

import threading
from typing import Any

COMPILE_EVENTS = "/jax/core/compile/"  # JAX's duration events of tracing, lowering and compiling

_lock = threading.Lock()
_seconds = 0.0
_listening = False


def _heard(event: str, duration: float, **_: Any) -> None:
    global _seconds
    if event.startswith(COMPILE_EVENTS):
        with _lock:
            _seconds += float(duration)


def jax_compile_seconds() -> float:
    """Seconds JAX has spent tracing, lowering and compiling in this process since the first
    call (which starts listening; a JAX without monitoring events reports 0)."""
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
    return _seconds


def simulator_compile_seconds(sim: Any) -> float:
    """Seconds `sim` has spent capturing its graphs and compiling its kernels (0 for a
    simulator that compiles nothing: C MuJoCo)."""
    return float(getattr(sim, "capture_seconds", 0.0) or 0.0)


def compile_seconds(sim: Any = None) -> float:
    """JAX's compilation seconds so far, plus `sim`'s."""
    return jax_compile_seconds() + simulator_compile_seconds(sim)
