"""An evaluation's trials run: in this process, or split across processes, one per GPU.

`run_trials` runs a list of trials (failure, scenario, ASM, seed) scenario by scenario: the
trials of a scenario share its planner simulator and run side by side
(`lmjx.evaluation.lockstep`), and each finished trial becomes a record (`trial_record`),
handed to `emit` as it ends.

`run_in_processes` splits the trials across `n` child processes (each scenario's trials dealt
in turn, so that every process batches a share of every scenario): child k simulates on GPU
k mod the GPUs (MuJoCo Warp's device and JAX's default device; several processes may share a
GPU: a process's host work runs under its own interpreter lock), runs as many trials at once
as the cores shared out, and sends each record back as its trial ends;
this process receives them, in whatever order they end, and hands them to `emit`.  A trial's
record does not depend on the process that ran it or on the trials beside it, so the records
are those one process makes (tests/test_evaluate_processes.py).  A child's error reaches this
process as the child's own; Ctrl-C (which reaches this process alone) stops the children.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import signal
import traceback
from collections.abc import Callable
from dataclasses import replace
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any

from lmjx.evaluation.lockstep import run_lockstep
from lmjx.evaluation.provenance import trial_provenance
from lmjx.mapfile.read import MapFile, load_map
from lmjx.model.robot import Robot
from lmjx.planner.records import TrialResult
from lmjx.planner.transit import TransitPlanner
from lmjx.planner.trial import make_simulator, setup_trial
from lmjx.runtime.child import annotated, start_child
from lmjx.runtime.cores import usable_cores
from lmjx.types import PlannerConfig

Key = tuple[str, int, str, int]  # (failure, scenario, ASM, seed)


def trial_record(robot: Robot, config, run: dict[str, Any], key: Key, res: TrialResult) -> dict[str, Any]:
    """The record results.json keeps of a trial, with its scene (`scene_record`: a shipped
    scenario's number and task set, a scene file's text; enough to replay the trial alone)."""
    from lmjx.sim.scenefile import scene_record

    f, s, a, seed = key
    return {
        "robot": robot.key,
        "tasks": config.tasks,
        "failure": f,
        "scenario": s,
        "scene": scene_record(config.task(s, robot), robot),
        "asm": a,
        "seed": seed,
        "success": res.success,
        "actions": res.actions,
        "planning_s": round(res.planning_s, 3),  # the sum of its decisions' latencies
        "compile_s": round(res.compile_s, 3),  # not in planning_s (lmjx.runtime.compiletime)
        "execution_s": round(res.execution_s, 3),
        "sim_steps": res.sim_steps,  # the planning limit's count (provenance: planner.max_sim_steps)
        "final_distance_m": round(res.final_distance, 4),
        "end": res.reason,
        "stopped": res.stopped,
        "sim": config.backend if a != "random" else "none",
        "candidates": config.planner.greedy_candidates if a == "greedy" else None,
        "asm_settings": config.planner.settings(a),
        "steps": res.action_records(),
        # the decision that found no action, where one ended the trial: why (`StepRecord.no_action`)
        **({"no_action": res.steps[-1].no_action} if res.steps and res.steps[-1].no_action else {}),
        "run": run["id"],  # (its entry in the file's `runs`)
        "provenance": trial_provenance(run, f, a),
    }


def run_trials(
    robot: Robot,
    maps: dict[str, MapFile],
    config,
    run: dict[str, Any],
    keys: list[Key],
    emit: Callable[[dict[str, Any]], None],
    gpu_config=None,
    on_group: Callable[[int, int], None] | None = None,
    threads: int | None = None,
) -> None:
    """Run the trials `keys` of `config` (an `EvalConfig`), scenario by scenario, handing each
    record to `emit` as its trial ends.  `gpu_config`: the GPU simulator's (its device);
    `on_group(scenario, trials)` is told as each scenario's trials start; `threads`: trials in
    flight at once (default: the cores)."""
    threads = threads or usable_cores()
    for s in sorted({k[1] for k in keys}):
        group = [k for k in keys if k[1] == s]
        task = config.task(s, robot)  # once per scenario: its trials share it and the simulator
        sim = (
            make_simulator(robot, task, config.backend, gpu_config, servo=config.planner.servo)
            if any(k[2] != "random" for k in group)
            else None
        )
        batched = bool(sim is not None and sim.prefers_batches)
        trials = []
        for f, _, a, seed in group:
            pc = PlannerConfig(**{**config.planner.__dict__, "asm": a})
            # each trial its own transit planner: trials run side by side (their roadmap's graph is shared)
            transits = TransitPlanner(robot, maps[f].failure, batched=batched)
            setup = setup_trial(robot, maps[f], task, pc, seed, sim if a != "random" else None, transits)
            trials.append((setup.planner.trial(setup.world, setup.layout, setup.planner_seed), setup.world))
        if on_group is not None:
            on_group(s, len(group))

        def finished(i: int, res: TrialResult, group: list[Key] = group) -> None:
            emit(trial_record(robot, config, run, group[i], res))

        # as many trials in flight as cores: their host work gains nothing from more (and each
        # holds a decision's screening, up to a gigabyte on a map of 1,000,000 edges: 90 trials
        # at once ran a 128 GB host out of memory), a GPU answers all their candidates in one
        # batch, C MuJoCo uses the cores itself, and a stopped run keeps the trials that ended
        run_lockstep(trials, sim, finished, window=threads)


def deal(keys: list[Key], n: int) -> list[list[Key]]:
    """`keys` in `n` shares: each scenario's trials dealt in turn (every share batches a part
    of every scenario); each share keeps the keys' order."""
    shares: list[list[Key]] = [[] for _ in range(n)]
    seen: dict[int, int] = {}
    for k in keys:
        j = seen.get(k[1], 0)
        seen[k[1]] = j + 1
        shares[j % n].append(k)
    return [s for s in shares if s]


def run_in_processes(
    robot: Robot,
    maps: dict[str, MapFile],
    config,
    run: dict[str, Any],
    keys: list[Key],
    n: int,
    emit: Callable[[dict[str, Any]], None],
) -> None:
    """`run_trials` over `keys` split across `n` child processes (`deal`), child k on GPU k
    where the simulator is the GPU's; each record handed to `emit` here as it arrives."""
    shares = deal(keys, n)
    children: list[tuple[Any, Connection, Connection]] = []
    env = dict(os.environ, XLA_PYTHON_CLIENT_PREALLOCATE="false")  # the GPU's memory taken as needed
    try:
        for k, share in enumerate(shares):
            proc, to_child, from_child = start_child("lmjx.evaluation.workers", "serve", env)
            children.append((proc, to_child, from_child))
            threads = max(1, usable_cores() // len(shares))  # (the cores shared out)
            work = (robot, {f: str(m.path) for f, m in maps.items()}, config, run, share, k, threads)
            to_child.send_bytes(pickle.dumps(work))
        open_pipes = {c[2]: c for c in children}
        while open_pipes:
            for conn in wait(list(open_pipes)):
                proc = open_pipes[conn][0]
                try:
                    kind, payload = conn.recv()
                except EOFError:
                    proc.wait()
                    del open_pipes[conn]
                    raise RuntimeError(
                        f"an evaluation process ended without a word (exit code {proc.returncode})"
                    ) from None
                if kind == "record":
                    emit(payload)
                elif kind == "done":
                    del open_pipes[conn]
                else:  # ("error", (exception or its text, traceback))
                    e, trace = payload
                    raise annotated(e if isinstance(e, BaseException) else RuntimeError(e), trace,
                                    "an evaluation process")  # fmt: skip
    finally:
        for proc, to_child, from_child in children:
            to_child.close()
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGTERM)
            proc.wait()
            from_child.close()


def serve(inbox_fd: int, outbox_fd: int) -> None:
    """A child's life: its trials (robot, map paths, config, run, keys, its index k) come from
    the parent; each record goes back as its trial ends, then ("done", None)."""
    inbox = Connection(inbox_fd, writable=False)
    outbox = Connection(outbox_fd, readable=False)
    try:
        robot, paths, config, run, keys, k, threads = pickle.loads(inbox.recv_bytes())
        gpu_config = _own_gpu(k) if config.backend == "gpu" else None
        maps = {f: load_map(Path(p), robot) for f, p in paths.items()}
        run_trials(robot, maps, config, run, keys, lambda record: outbox.send(("record", record)), gpu_config,
                   threads=threads)  # fmt: skip
        outbox.send(("done", None))
    except BaseException as e:  # (the parent raises it)
        trace = traceback.format_exc()
        try:
            pickle.dumps(e)
            outbox.send(("error", (e, trace)))
        except Exception:  # an exception that does not pickle: its text
            outbox.send(("error", (f"{type(e).__name__}: {e}", trace)))


def _own_gpu(k: int):
    """The GPU simulator's settings on GPU k (of those this process sees), JAX's work placed there too."""
    import jax

    from lmjx.sim.gpu import GpuSimConfig

    gpus = [d for d in jax.devices() if d.platform == "gpu"]
    if gpus:
        jax.config.update("jax_default_device", gpus[k % len(gpus)])
    return replace(GpuSimConfig(), device=f"cuda:{k % max(1, len(gpus))}")
