"""Compiling is not planning: a decision's compilation (JAX's, a simulator's) is recorded in
`compile_s` and left out of `planning_s`, whichever way its simulations are answered."""

from __future__ import annotations

import os
import threading
import time
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from lmjx.evaluation.lockstep import _simulate
from lmjx.planner.edge_planner import Planner, simulate_request
from lmjx.planner.phases import PhaseClock
from lmjx.planner.records import StepRecord
from lmjx.planner.requests import Simulate
from lmjx.runtime.compiletime import compile_seconds, jax_compile_seconds

SIM_COMPILE = 0.2  # [s] what the stand-in simulator "compiles" on its first call


class CompilingSim:
    """A simulator that spends SIM_COMPILE s capturing on its first call and reports it as
    the GPU simulator does (`capture_seconds`)."""

    def __init__(self, batches: bool) -> None:
        self.prefers_batches = batches
        self.capture_seconds = 0.0

    def simulate(self, robot_q, objects, actions):
        if self.capture_seconds == 0.0:
            t0 = time.perf_counter()
            time.sleep(SIM_COMPILE)
            self.capture_seconds += time.perf_counter() - t0
        return np.zeros((len(actions), len(objects), 7))

    def simulate_many(self, requests):
        return [self.simulate(*r) for r in requests]


@pytest.mark.parametrize("batches", [False, True], ids=["one request", "lockstep batch"])
def test_compile_seconds_kept_out_of_planning(batches: bool) -> None:
    first_call = {}

    def decide(obs, rng):
        k = float(int.from_bytes(os.urandom(4), "little"))  # a new program: no compilation cache hit

        def work(x):  # enough operations that compiling them takes a measurable while
            for i in range(150):
                x = jnp.tanh(x @ x.T * 1e-3 + k + i)
            return x

        f = jax.jit(work)
        t0 = time.perf_counter()
        f(jnp.ones((64, 64))).block_until_ready()
        first_call["s"] = time.perf_counter() - t0
        yield Simulate(np.zeros(7), np.zeros((1, 7)), [SimpleNamespace(q=np.zeros((3, 7)))])  # (3 control points)
        return None, StepRecord(-1, 0, 0, None, 0.0, 0.0, 0.0)

    sim = CompilingSim(batches)
    jax_compile_seconds()  # listening from here
    t0 = time.perf_counter()
    steps = Planner._timed_decision(SimpleNamespace(decide=decide, clock=PhaseClock()), None, None)
    req = next(steps)
    answer = _simulate(sim, {0: req})[0] if batches else simulate_request(sim, req)
    assert answer.compile_s == pytest.approx(sim.capture_seconds, abs=1e-9)
    assert answer.seconds < 0.05
    with pytest.raises(StopIteration) as done:
        steps.send(answer)
    wall = time.perf_counter() - t0
    _, rec = done.value.value
    jax_part = rec.compile_s - sim.capture_seconds
    # JAX's events (lowering, compiling) account for a good part of the jitted function's
    # first call (alone 52-67 %; 27 % in a fresh clone's suite, where the compile-ahead
    # thread holds the GIL during the call's tracing: 0 were they not counted), and every
    # second of the decision is either planning or compiling
    assert jax_part >= 0.1 * first_call["s"]
    assert rec.planning_s + rec.compile_s == pytest.approx(wall, abs=0.05)
    assert rec.planning_s < wall - SIM_COMPILE
    assert rec.latency_s == rec.planning_s and rec.phase_s["compile"] == pytest.approx(rec.compile_s, abs=1e-4)
    assert rec.summary()["compile_s"] == round(rec.compile_s, 3)
    assert rec.sim_steps == 3  # what the planning limit counts: the request's control points


def test_simulator_without_compilation() -> None:
    """C MuJoCo's simulator compiles nothing: only JAX's seconds count."""
    assert compile_seconds(SimpleNamespace()) == jax_compile_seconds()


def test_compiling_on_another_thread_is_not_charged() -> None:
    """What another thread compiles (the suite's compile-ahead thread, say) is not this
    thread's: only the compiling thread's count grows."""
    k = float(int.from_bytes(os.urandom(4), "little"))
    here = jax_compile_seconds()
    seen = {}

    def other() -> None:
        before = jax_compile_seconds()
        jax.jit(lambda x: jnp.tanh(x) * k)(jnp.ones(8)).block_until_ready()
        seen["other"] = jax_compile_seconds() - before

    t = threading.Thread(target=other)
    t.start()
    t.join()
    assert seen["other"] > 0
    assert jax_compile_seconds() == here


def test_programs_compiled_side_by_side_count_once_and_are_told() -> None:
    """A build's compile seconds are the wall time during which something compiled (never
    above the build's wall time), and a long compilation is told as it ends."""
    from lmjx.runtime.compiletime import compile_span, compile_wall_seconds, telling_compiled, told_compiled

    t0 = time.perf_counter()

    def compiling() -> None:
        with compile_span():
            time.sleep(0.3)

    threads = [threading.Thread(target=compiling) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    wall = time.perf_counter() - t0
    assert 0.29 <= compile_wall_seconds(t0) <= wall
    heard = []
    with telling_compiled(lambda name, s: heard.append((name, s))):
        told_compiled("the edges' rollout", 12.0)
        told_compiled("a program loaded from the cache", 0.1)
    told_compiled("after", 5.0)
    assert heard == [("the edges' rollout", 12.0)]
