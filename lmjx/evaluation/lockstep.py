"""Many trials at once: their host work side by side, their simulations answered together.

Each trial is a planner generator (`Planner.trial`) that yields `Simulate` and `Execute`
requests.  `run_lockstep` runs every trial in flight on a thread of its own: its decisions'
host work (the offer, the transits, the scoring: numpy, JAX and C MuJoCo, which release the
interpreter lock for their work) and its executions in the "real" world overlap with the
other trials'.  With a simulator that prefers batches (MuJoCo Warp on a GPU) a trial's
`Simulate` waits while the others compute: once no trial is computing (every one waits for a
simulation or has ended), or the waiting rollouts fill the simulator's largest batch, all of
them are simulated in one `simulate_many` call.  A simulator that does not prefer batches (C
MuJoCo, which uses every core itself) is called per request, one request at a time.  A
trial's decisions do not depend on which other trials share its batches or run beside it
(each has its own planner state: `Planner`, `TransitPlanner`): this only changes how fast
they are made.

A `window` keeps at most that many trials in flight, the next starting as one ends, so a run
stopped part-way keeps the trials that ended (each is recorded as it ends, in the calling
thread, by `on_done`).

Planning time: each decision waited for the whole batch its candidates were simulated in,
and its latency counts the batch's wall seconds; the part of them spent on other trials'
candidates (in proportion to the rollouts) is recorded apart (`StepRecord.shared_s`).  The
seconds a batch spent compiling (`lmjx.runtime.compiletime`: the GPU's graphs and kernels on
first use) are kept out of planning time.
"""

from __future__ import annotations

import threading
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

# waiting rollouts that are simulated at once, computing trials or not (or a simulator's `full_batch`)
FULL_BATCH = 4096


class _StopError(Exception):
    """The run is stopping (another trial failed, or the caller was interrupted)."""


class _Board:
    """What the trials in flight are doing: how many compute, the simulations waiting, the
    trials ended (results or errors), under one condition."""

    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.computing = 0
        self.waiting: dict[int, Simulate] = {}
        self.answers: dict[int, Simulated] = {}
        self.ended: list[tuple[int, TrialResult | BaseException]] = []
        self.stopping = False

    def simulate(self, i: int, req: Simulate) -> Simulated:
        """Trial i's simulation, answered with the others' (blocks until then)."""
        with self.cond:
            self.waiting[i] = req
            self.computing -= 1
            self.cond.notify_all()
            while i not in self.answers and not self.stopping:
                self.cond.wait()
            if self.stopping:
                raise _StopError
            self.computing += 1
            return self.answers.pop(i)


def run_lockstep(
    trials: list[tuple[Generator[Any, Any, TrialResult], Executor]],
    sim: Simulator | None,
    on_done: Callable[[int, TrialResult], None],
    threads: int = 1,
    window: int | None = None,
) -> None:
    """Drive `trials` (generator, executor) to their ends; `on_done(index, result)` is called
    in this thread as each finishes; at most `window` (None: all) are in flight at once, in
    order.  `threads` is kept for callers: every trial in flight has a thread."""
    if not trials:
        return
    batched = bool(sim is not None and sim.prefers_batches)
    width = len(trials) if window is None else max(1, min(window, len(trials)))
    full = int(getattr(sim, "full_batch", FULL_BATCH))
    board = _Board()
    sim_lock = threading.Lock()  # a simulator that does not prefer batches: one request at a time

    def one(i: int) -> None:
        gen, executor = trials[i]
        answer: Any = None
        try:
            while True:
                try:
                    req = gen.send(answer)
                except StopIteration as done:
                    result: TrialResult | BaseException = done.value
                    break
                if board.stopping:
                    raise _StopError
                if isinstance(req, Execute):
                    answer = execute_request(executor, req)
                elif batched:
                    answer = board.simulate(i, req)
                else:
                    assert sim is not None, "a trial asked for a simulation but no simulator was given"
                    with sim_lock:
                        answer = simulate_request(sim, req)
        except _StopError:
            gen.close()
            result = _StopError()
        except BaseException as e:  # (given to the calling thread, which raises it)
            result = e
        with board.cond:
            board.computing -= 1
            board.ended.append((i, result))
            board.cond.notify_all()

    order = iter(range(len(trials)))
    in_flight = 0
    with ThreadPoolExecutor(width, thread_name_prefix="lmjx-trial") as pool:

        def start_next() -> bool:
            nonlocal in_flight
            i = next(order, None)
            if i is None:
                return False
            with board.cond:
                board.computing += 1
            in_flight += 1
            pool.submit(one, i)
            return True

        for _ in range(width):
            start_next()
        try:
            while in_flight:
                batch: dict[int, Simulate] = {}
                with board.cond:
                    while not board.ended:
                        rollouts = sum(r.rollouts for r in board.waiting.values())
                        if board.waiting and (board.computing == 0 or rollouts >= full):
                            batch, board.waiting = board.waiting, {}
                            break
                        board.cond.wait(timeout=1.0)
                    ended, board.ended = board.ended, []
                for i, result in ended:
                    in_flight -= 1
                    if isinstance(result, BaseException):
                        raise result
                    on_done(i, result)
                    start_next()
                if batch:
                    assert sim is not None
                    answers = _simulate(sim, batch)
                    with board.cond:
                        board.answers.update(answers)
                        board.cond.notify_all()
        except BaseException:
            with board.cond:  # the trials in flight stop at their next request
                board.stopping = True
                board.cond.notify_all()
            raise


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
