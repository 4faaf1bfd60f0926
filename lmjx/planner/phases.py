"""Where a decision's wall time goes: named phases, with compiling kept apart.

A decision (`Planner.decide`) runs its parts inside `PhaseClock.phase(name)` blocks:
  * offer:    the edges over the target (turned copies included) and their checks: starts
              clear of the scene, edges that act on the target and keep off fixed obstacles;
  * transit:  the transits that make the offered edges actions (straight, through the park
              pose, along the roadmap, after a retreat or an escape);
  * simulate: the candidates' simulation and their scoring (Greedy, Lazy);
  * rescore:  Greedy's second simulation of its best candidates from redrawn starts;
  * execute:  the chosen action in the "real" world (not part of the decision's latency);
  * compile:  what JAX or the simulator compiled meanwhile (taken out of the phase it fell in).
A block opened inside another pauses the outer one, so every second counts once.  The clock
is per trial (a thread of its own may run each trial's decisions).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

from lmjx.runtime.compiletime import jax_compile_seconds

PHASES = ("offer", "transit", "simulate", "rescore", "execute", "compile")
LATENCY_PHASES = ("offer", "transit", "simulate", "rescore")  # observation to chosen action


class PhaseClock:
    """Seconds per phase (`PHASES`) since the last `reset`."""

    def __init__(self) -> None:
        self.seconds = dict.fromkeys(PHASES, 0.0)
        self._stack: list[tuple[str, float, float]] = []  # (phase, since, compile seconds then)

    def reset(self) -> None:
        self.seconds = dict.fromkeys(PHASES, 0.0)
        self._stack.clear()

    def _charge(self, now: float, compiled: float) -> None:
        name, since, c0 = self._stack[-1]
        c = max(0.0, compiled - c0)
        self.seconds[name] += max(0.0, now - since - c)
        self.seconds["compile"] += c

    @contextmanager
    def phase(self, name: str) -> Iterator[None]:
        """Count the wall time of the block as `name` (what JAX compiled meanwhile as compile)."""
        now, compiled = time.perf_counter(), jax_compile_seconds()
        if self._stack:
            self._charge(now, compiled)
        self._stack.append((name, now, compiled))
        try:
            yield
        finally:
            now, compiled = time.perf_counter(), jax_compile_seconds()
            self._charge(now, compiled)
            self._stack.pop()
            if self._stack:  # the outer phase resumes
                outer = self._stack[-1][0]
                self._stack[-1] = (outer, now, compiled)

    def add(self, name: str, seconds: float) -> None:
        """Count `seconds` measured elsewhere (a simulation answered by the driver) as `name`."""
        self.seconds[name] += max(0.0, seconds)

    def latency(self) -> float:
        """The decision's seconds from the observation to the chosen action, compiling excluded."""
        return sum(self.seconds[k] for k in LATENCY_PHASES)

    def rounded(self) -> dict[str, float]:
        return {k: round(v, 4) for k, v in self.seconds.items()}
