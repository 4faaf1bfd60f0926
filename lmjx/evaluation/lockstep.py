"""Many trials at once: their planners' requests answered together.

Each trial is a planner generator (`Planner.trial`) that yields `Simulate` and `Execute`
requests.  `run_lockstep` advances every trial of a group to its next request, then answers
all the simulation requests with one `simulate_many` call (on a GPU: one batch of every
trial's candidates) and all the executions on a pool of threads (C MuJoCo releases the
interpreter lock while it steps).  A trial's decisions do not depend on which other trials
share its batches: this only changes how fast they are made.

A `window` keeps at most that many trials in flight, the next starting as one ends: with a
simulator that does not prefer batches (C MuJoCo) nothing is gained by advancing every trial
together, and a run stopped part-way keeps the trials that ended (each is recorded as it
ends) instead of losing a whole group that had not finished.

Planning time: each decision waited for the whole batch its candidates were simulated in,
and its latency counts the batch's wall seconds; the part of them spent on other trials'
candidates (in proportion to the rollouts) is recorded apart (`StepRecord.shared_s`).  A
simulator that does not prefer batches is called per request, each its own call.  The seconds
a batch spent compiling (`lmjx.runtime.compiletime`: the GPU's graphs and kernels on first use)
are kept out of planning time.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Generator
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from lmjx.planner.edge_planner import execute_request, simulate_request
from lmjx.planner.records import TrialResult
from lmjx.planner.requests import Execute, Simulate, Simulated
from lmjx.runtime.compiletime import compile_seconds
from lmjx.types import Executor, Simulator


def run_lockstep(
    trials: list[tuple[Generator[Any, Any, TrialResult], Executor]],
    sim: Simulator | None,
    on_done: Callable[[int, TrialResult], None],
    threads: int = 1,
    window: int | None = None,
) -> None:
    """Drive `trials` (generator, executor) to their ends; `on_done(index, result)` is
    called as each finishes; at most `window` (None: all) are in flight at once, in order."""
    width = len(trials) if window is None else max(1, window)
    answers: dict[int, Any] = {i: None for i in range(min(width, len(trials)))}
    waiting = iter(range(len(answers), len(trials)))
    with ThreadPoolExecutor(max(1, threads)) as pool:
        while answers:
            sims: dict[int, Simulate] = {}
            execs: dict[int, Execute] = {}
            answers_next: dict[int, Any] = {}
            for i, answer in answers.items():
                try:
                    req = trials[i][0].send(answer)
                except StopIteration as done:
                    on_done(i, done.value)
                    nxt = next(waiting, None)
                    if nxt is not None:  # starts with the next round
                        answers_next[nxt] = None
                    continue
                if isinstance(req, Simulate):
                    sims[i] = req
                else:
                    execs[i] = req
            answers = answers_next
            futures = {i: pool.submit(execute_request, trials[i][1], req) for i, req in execs.items()}
            if sims:
                assert sim is not None, "a trial asked for a simulation but no simulator was given"
                answers.update(_simulate(sim, sims))
            answers.update({i: f.result() for i, f in futures.items()})


def _simulate(sim: Simulator, sims: dict[int, Simulate]) -> dict[int, Simulated]:
    if not sim.prefers_batches:
        return {i: simulate_request(sim, req) for i, req in sims.items()}
    c0, t0 = compile_seconds(sim), time.perf_counter()
    parts = [r.parts() for r in sims.values()]  # a request from several start states: one part each
    flat = sim.simulate_many([p for ps in parts for p in ps])
    compiled = compile_seconds(sim) - c0
    seconds = max(0.0, time.perf_counter() - t0 - compiled)
    total = max(1, sum(r.rollouts for r in sims.values()))
    finals, at = [], 0
    for ps in parts:
        finals.append(np.concatenate(flat[at : at + len(ps)]))
        at += len(ps)
    return {
        i: Simulated(final, seconds, compiled * req.rollouts / total, seconds * (1 - req.rollouts / total))
        for (i, req), final in zip(sims.items(), finals, strict=True)
    }
