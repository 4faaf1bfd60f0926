"""Does a simulator make the planner's decisions as C MuJoCo does?  Measured over many Greedy
decisions, not one.

Decision states: for each failure, scenario and seed, the trial's start (arm parked, objects
as laid out) and the states after 1 .. `depth - 1` random actions executed in that trial's
"real" world (objects pushed about, arm elsewhere).  In each state the planner's candidates
(edges over the target, in the trial's random order, with transits clear of the scene as
observed, retreating along the last edge as the planner's do) are
simulated by the simulator under test and by C MuJoCo's whole scene (the reference).  Per
decision: the candidate each picks (lowest score), how much worse by the reference's score
the tested pick is (the choice gap), and where the target ends in both.  The simulator under
test sees all decisions of a scenario in one `simulate_many` call (and its rescoring in one more).

With rescoring (`Rescore`, Greedy's `PlannerConfig.rescore_top` and `rescore_draws`, as the
evaluation runs it) each simulator's pick is Greedy's rescored choice: its `top` best candidates
simulated again from `draws - 1` redrawn starts (`scoring.drawn_starts`, the same draws for
both simulators), the lowest mean score taken.  The reference rescores the tested simulator's
top candidates too, so the choice gap is the reference's mean score of the tested pick less
that of its own.
"""

from __future__ import annotations

import gzip
import os
import pickle
import statistics
import time
import zlib
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from multiprocessing import get_context

import numpy as np

from lmjx.errors import ConfigError
from lmjx.mapfile.read import MapFile
from lmjx.model.robot import Robot
from lmjx.planner.edge_planner import edges_over_target
from lmjx.planner.scoring import _score_field, drawn_starts, score, table_bounds
from lmjx.planner.transit import TransitPlanner, after_executing
from lmjx.runtime.fileio import atomic_path
from lmjx.sim.goalfield import GoalField
from lmjx.sim.realworld import SimulatedRealWorld
from lmjx.sim.scenarios import Scenario, sample_layout, scenario
from lmjx.types import Observation, PlannerConfig, Simulator

GAP_OK = 0.01  # [m] a pick this close to the best by the reference's score counts as the same choice
# The agreement test's maps and decisions (tests/test_simulate_gpu.py).  Chosen before the
# test's first run in this configuration and used nowhere else; they must not be changed after
# it (a test re-run on other seeds until it passes measures nothing): maps built with seed
# 4049; decisions from trial seeds 700-711 ("real" worlds and layouts 10,700-10,711).  Seeds
# these must stay clear of: maps of seed 0 and 2026, trial seeds 0-11 and 500-511 (worlds
# 10,000-10,011 and 10,500-10,511), the evaluation's trials 1,000-3,014.  The configuration the
# evaluation runs: the planner's servo model "robot" and Greedy's rescoring (`RESCORE`), in
# both simulators.  Its pass, set with the seeds: at least MIN_DECISIONS decisions, the same
# rescored pick or one within GAP_OK in at least MIN_SAME_OR_NEAR of them, target ends a median
# of at most MAX_MEDIAN_END_DIFF apart, nothing non-finite.
MAP_SEED = 4049
FIRST_SEED = 700
OUT_OF_SAMPLE_SEEDS = 12
SERVO = "robot"  # `PlannerConfig.servo`'s default
MIN_DECISIONS = 200
MIN_SAME_OR_NEAR = 0.95
MAX_MEDIAN_END_DIFF = 1e-4  # [m]
DECISIONS_FORMAT = "lmjx-agreement-decisions/2"  # `save_decisions`' files


@dataclass
class Decision:
    failure: str
    scenario: int
    seed: int
    depth: int  # random actions executed before this decision
    observation: Observation
    actions: list


def decision_states(
    robot: Robot,
    maps: dict[str, MapFile],
    scenarios: tuple[int, ...],
    seeds: int,
    depth: int,
    candidates: int,
    first_seed: int = 0,
    workers: int = 1,
) -> list[Decision]:
    """Decisions with their candidate actions (see the module docstring), for trial seeds
    `first_seed` .. `first_seed + seeds - 1` (seed s: layout and "real" world 10,000 + s,
    the planner's random order from s).  Each (failure, scenario, seed) is a chain of its
    own: with `workers` > 1 the chains run in that many processes (spawned, JAX on the CPU;
    the same decisions, in the same order, as one process makes: building them is the
    agreement test's longest part, about 16 s a decision on one core)."""
    chains = [(f, s, seed) for f in maps for s in scenarios for seed in range(first_seed, first_seed + seeds)]
    if workers <= 1 or len(chains) <= 1:
        planners: dict[str, TransitPlanner] = {}
        return [d for c in chains for d in _chain(robot, maps, planners, *c, depth, candidates)]
    paths = {f: str(m.path) for f, m in maps.items()}
    jobs = [(robot.key, paths, *c, depth, candidates) for c in chains]
    spawn = get_context("spawn")
    with ProcessPoolExecutor(min(workers, len(chains)), mp_context=spawn, initializer=_cpu_worker) as pool:
        return [d for found in pool.map(_chain_job, jobs) for d in found]


def _chain(
    robot: Robot,
    maps: dict[str, MapFile],
    planners: dict[str, TransitPlanner],
    f: str,
    s: int,
    seed: int,
    depth: int,
    candidates: int,
) -> list[Decision]:
    """The decisions of one trial seed (`decision_states`); `planners`: one TransitPlanner per
    failure, made here when missing."""
    mf = maps[f]
    assert mf.edges is not None and mf.reach is not None
    if f not in planners:
        planners[f] = TransitPlanner(robot, mf.failure, batched=True)
    tp = planners[f]
    sc = scenario(s, robot.profile.task_scale, "hard")
    rng = np.random.default_rng(seed)
    world = SimulatedRealWorld(robot, 10_000 + seed)
    obs = world.reset(sample_layout(sc, 10_000 + seed), tp.park)
    came_from, trail = None, obs.robot_q[None].copy()  # as `Planner.trial` keeps them
    out = []
    for k in range(depth):
        target = obs.objects[0, :2]
        edges = edges_over_target(mf.edges, mf.reach, target, float(sc.target.half[0]), 0.01)
        tp.set_scene(sc, obs.objects)  # the planner's candidates: transits clear of the scene
        acts = tp.actions(mf.edges, rng.permutation(edges), obs.robot_q, candidates, came_from, trail)
        if len(acts) < 2:
            break
        out.append(Decision(f, s, seed, k, obs, acts))
        if k + 1 < depth:
            act = acts[int(rng.integers(len(acts)))]
            obs = world.execute(act)
            came_from, trail = after_executing(act, trail, mf.edges.q_start.dtype)
    return out


_WORKER: dict = {}  # a worker process's robot, maps and planners (`_chain_job`)


def _chain_job(job: tuple) -> list[Decision]:
    """`_chain` in a worker process: the robot and the maps loaded once per process."""
    from lmjx.mapfile.read import load_map
    from lmjx.model.robot import as_robot

    key, paths, f, s, seed, depth, candidates = job
    loaded = (key, tuple(sorted(paths.items())))
    if _WORKER.get("key") != loaded:
        robot = as_robot(key)
        maps = {g: load_map(p, robot) for g, p in paths.items()}
        _WORKER.clear()
        _WORKER.update(key=loaded, robot=robot, maps=maps, planners={})
    return _chain(_WORKER["robot"], _WORKER["maps"], _WORKER["planners"], f, s, seed, depth, candidates)


def _cpu_worker() -> None:
    """A worker process's start, before its JAX starts a backend: JAX on the CPU, one thread
    (a GPU is the simulators', and each process would otherwise take most of its memory)."""
    import jax

    one_thread = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    os.environ["XLA_FLAGS"] = " ".join(x for x in (os.environ.get("XLA_FLAGS"), one_thread) if x)
    os.environ["JAX_PLATFORMS"] = "cpu"
    jax.config.update("jax_platforms", "cpu")


@dataclass(frozen=True)
class Rescore:
    """Greedy's rescoring (`PlannerConfig.rescore_top`, `rescore_draws`): the `top` best
    candidates simulated again from `draws - 1` redrawn starts; `top` 0: none."""

    top: int = 0
    draws: int = 2


RESCORE = Rescore(PlannerConfig().rescore_top, PlannerConfig().rescore_draws)  # the evaluation's Greedy


def measure(
    robot: Robot,
    decisions: list[Decision],
    tested: dict[int, Simulator],
    reference: dict[int, Simulator],
    rescore: Rescore = Rescore(),
    fields: dict[tuple[str, int], Callable] | None = None,
) -> dict:
    """Compare the simulators in `tested` with those in `reference` (C MuJoCo's whole scene),
    per scenario, on every decision; with `rescore`, on Greedy's rescored choice.  `fields`:
    the score's "closest" per (failure, scenario) (the planner's, `planner_fields`); default
    the path length to the goal (`GoalField`)."""
    rows = []
    seconds = {"tested": 0.0, "reference": 0.0}
    for s in sorted({d.scenario for d in decisions}):
        group = [d for d in decisions if d.scenario == s]
        sim, ref = tested[s], reference[s]
        sc = scenario(s, robot.profile.task_scale, "hard")
        plain = GoalField(sc, *table_bounds(robot))
        field = {d.failure: (fields or {}).get((d.failure, s), plain) for d in group}
        requests = [(d.observation.robot_q, d.observation.objects, d.actions) for d in group]
        finals, expected_all = _both(sim, ref, requests, seconds)
        scored = []
        for d, final, expected in zip(group, finals, expected_all, strict=True):
            finite = np.isfinite(final).all(axis=(1, 2))
            s_ref = score(sc, robot, expected, field[d.failure])
            s_new = score(sc, robot, np.where(finite[:, None, None], final, 1e3), field[d.failure])
            scored.append((s_new, s_ref, finite, final, expected))
        chosen = [(s_new, s_ref, s_ref, []) for s_new, s_ref, *_ in scored]  # (tested's, reference's, gap's, ends)
        if rescore.top > 0:
            chosen = _rescored(robot, sc, group, scored, field, rescore, sim, ref, seconds)
        for d, (s_new, s_ref, finite, final, expected), (by_new, by_ref, gap_by, more) in zip(
            group, scored, chosen, strict=True
        ):
            pick, best = int(np.argmin(by_new)), int(np.argmin(by_ref))
            ends = np.hypot(*(final[:, 0, :2] - expected[:, 0, :2]).T)[finite]
            rows.append(
                {
                    "failure": d.failure,
                    "scenario": s,
                    "seed": d.seed,
                    "depth": d.depth,
                    "candidates": len(d.actions),
                    "non_finite": int((~finite).sum()) + sum(bad for _, bad in more),
                    "same_choice": pick == best,
                    "choice_gap_m": float(gap_by[pick] - gap_by[best]),
                    "first_pass_same_choice": int(np.argmin(s_new)) == int(np.argmin(s_ref)),
                    "target_end_diff_m": np.concatenate([ends, *(m[0] for m in more)]).tolist(),
                    "rescored_ends": int(sum(len(m[0]) for m in more)),
                }
            )
    diffs = np.concatenate([r["target_end_diff_m"] for r in rows]) if rows else np.zeros(0)
    ok = [r["same_choice"] or r["choice_gap_m"] <= GAP_OK for r in rows]
    return {
        "decisions": len(rows),
        "candidates": int(sum(r["candidates"] for r in rows)),
        "rescore": {"top": rescore.top, "draws": rescore.draws},
        "same_choice": float(np.mean([r["same_choice"] for r in rows])) if rows else float("nan"),
        "same_or_within_1cm": float(np.mean(ok)) if rows else float("nan"),
        "first_pass_same_choice": float(np.mean([r["first_pass_same_choice"] for r in rows])) if rows else float("nan"),
        "choice_gap_m": {
            "median": statistics.median(r["choice_gap_m"] for r in rows) if rows else float("nan"),
            "max": max((r["choice_gap_m"] for r in rows), default=float("nan")),
        },
        "target_end_diff_m": {
            "n": len(diffs),
            "median": float(np.median(diffs)) if len(diffs) else float("nan"),
            "p90": float(np.quantile(diffs, 0.9)) if len(diffs) else float("nan"),
            "max": float(diffs.max()) if len(diffs) else float("nan"),
        },
        "non_finite": int(sum(r["non_finite"] for r in rows)),
        "seconds": seconds,
        "per_decision": [{k: v for k, v in r.items() if k != "target_end_diff_m"} for r in rows],
    }


def _both(sim: Simulator, ref: Simulator, requests: list, seconds: dict, ref_requests: list | None = None) -> tuple:
    """The tested simulator's results of `requests` and the reference's of `ref_requests`
    (default the same), timed into `seconds`."""
    t0 = time.perf_counter()
    finals = sim.simulate_many(requests)
    seconds["tested"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    theirs = requests if ref_requests is None else ref_requests
    # a batching reference (another GPU simulator) sees the decisions in the other order
    expected = ref.simulate_many(theirs[::-1])[::-1] if ref.prefers_batches else ref.simulate_many(theirs)
    seconds["reference"] += time.perf_counter() - t0
    return finals, expected


def _rescored(
    robot: Robot,
    sc: Scenario,
    group: list[Decision],
    scored: list[tuple],
    field: dict,
    rescore: Rescore,
    sim: Simulator,
    ref: Simulator,
    seconds: dict,
) -> list[tuple]:
    """Greedy's rescoring (`Planner.decide`) in both simulators, for every decision of one
    scenario: per decision what each minimises (the tested simulator's mean over its top
    candidates, inf elsewhere; the reference's over its own top), the reference's mean over
    both tops (the choice gap's measure), and per redrawn start the target ends' differences
    of the candidates both rescored and the tested simulator's non-finite results there."""
    resting = np.array([b.zc for b in sc.movable])
    plans, tested_req, ref_req = [], [], []
    for d, (s_new, s_ref, *_) in zip(group, scored, strict=True):
        top_new = np.argsort(s_new, kind="stable")[: rescore.top]
        top_ref = np.argsort(s_ref, kind="stable")[: rescore.top]
        both = np.union1d(top_new, top_ref)
        rng = np.random.default_rng([d.seed, d.depth, d.scenario, zlib.crc32(d.failure.encode())])
        starts = drawn_starts(d.observation.objects, rescore.draws - 1, rng, resting)
        plans.append((top_new, top_ref, both, len(tested_req)))
        for start in starts:
            tested_req.append((d.observation.robot_q, start, [d.actions[int(i)] for i in top_new]))
            ref_req.append((d.observation.robot_q, start, [d.actions[int(i)] for i in both]))
    finals, expected = _both(sim, ref, tested_req, seconds, ref_req)
    out = []
    k = rescore.draws - 1
    for d, (s_new, s_ref, *_), (top_new, top_ref, both, at) in zip(group, scored, plans, strict=True):
        new = np.stack(finals[at : at + k])  # (draws - 1, len(top_new), n, 7)
        old = np.stack(expected[at : at + k])  # (draws - 1, len(both), n, 7)
        finite = np.isfinite(new).all(axis=(2, 3))
        f = field[d.failure]
        drawn_new = np.stack(
            [score(sc, robot, np.where(ok[:, None, None], x, 1e3), f) for x, ok in zip(new, finite, strict=True)]
        )
        drawn_ref = np.stack([score(sc, robot, x, f) for x in old])
        mean_new = (s_new[top_new] + drawn_new.sum(axis=0)) / (k + 1)
        mean_ref = (s_ref[both] + drawn_ref.sum(axis=0)) / (k + 1)
        by_new = np.full(len(s_new), np.inf)
        by_new[top_new] = np.where(np.isnan(mean_new), np.inf, mean_new)
        gap_by = np.full(len(s_ref), np.inf)
        gap_by[both] = mean_ref
        by_ref = np.full(len(s_ref), np.inf)
        by_ref[top_ref] = gap_by[top_ref]
        by_ref = np.where(np.isnan(by_ref), np.inf, by_ref)
        common = np.intersect1d(top_new, top_ref)
        i_new = [int(np.nonzero(top_new == c)[0][0]) for c in common]
        i_ref = [int(np.nonzero(both == c)[0][0]) for c in common]
        more = []
        for j in range(k):
            a, b = new[j][i_new], old[j][i_ref]
            ok = finite[j][i_new]
            more.append((np.hypot(*(a[:, 0, :2] - b[:, 0, :2]).T)[ok], int((~finite[j]).sum())))
        out.append((by_new, by_ref, gap_by, more))
    return out


def planner_fields(robot: Robot, maps: dict[str, MapFile], scenarios: tuple[int, ...]) -> dict:
    """Greedy's "closest" per (failure, scenario), as the planner scores with its defaults
    (`PlannerConfig`: the path length weighted by the map's push counts)."""
    cfg = PlannerConfig()
    out = {}
    for f, m in maps.items():
        assert m.edges is not None and m.reach is not None
        for s in scenarios:
            out[(f, s)] = _score_field(
                robot, m.failure, m.reach, m.edges, scenario(s, robot.profile.task_scale, "hard"), cfg
            )
    return out


def out_of_sample_decisions(
    robot: Robot, maps: dict[str, MapFile], seeds: int = OUT_OF_SAMPLE_SEEDS, workers: int | None = None
) -> tuple[list[Decision], float, int]:
    """The agreement test's decisions (trial seeds FIRST_SEED onward, the three scenarios,
    depth 3, up to 64 candidates; built in `workers` processes, default one per usable core),
    the seconds they took and the workers.  They need no simulator: a machine without a GPU
    may build them for one with (`save_decisions`, `benchmarks/agreement_run.py
    --save-decisions`)."""
    from lmjx.runtime.cores import usable_cores

    workers = usable_cores() if workers is None else workers
    t0 = time.perf_counter()
    decisions = decision_states(robot, maps, (1, 2, 3), seeds, 3, 64, first_seed=FIRST_SEED, workers=workers)
    return decisions, time.perf_counter() - t0, workers


def out_of_sample(
    robot: Robot,
    maps: dict[str, MapFile],
    tested: dict[int, Simulator],
    reference: dict[int, Simulator],
    seeds: int = OUT_OF_SAMPLE_SEEDS,
    workers: int | None = None,
    built: tuple[list[Decision], float, int] | None = None,
) -> dict:
    """The agreement test's measurement: its decisions (`out_of_sample_decisions`) measured by
    `measure` in the evaluation's configuration (Greedy's rescoring `RESCORE` and score,
    `planner_fields`; the simulators the caller's, with servo model `SERVO`), with the seeds and
    the seconds the decisions took.  `built`: what `out_of_sample_decisions` returned before
    (elsewhere, from these maps)."""
    if built is None:
        built = out_of_sample_decisions(robot, maps, seeds, workers)
    decisions, took, workers = built
    report = measure(robot, decisions, tested, reference, RESCORE, planner_fields(robot, maps, (1, 2, 3)))
    report["seconds"]["decisions"] = took
    return report | {"map_seed": MAP_SEED, "first_seed": FIRST_SEED, "seeds": seeds, "servo": SERVO,
                     "decision_workers": workers}  # fmt: skip


def save_decisions(
    path: str | os.PathLike, built: tuple[list[Decision], float, int], maps: dict[str, MapFile], seeds: int
) -> None:
    """Write what `out_of_sample_decisions` returned (decisions, seconds, workers) for a
    machine with a GPU to measure: a gzip'd pickle, the maps' seed and sizes beside them,
    written atomically."""
    decisions, took, workers = built
    meta = {f: {"seed": m.edges.config.seed, "edges": int(m.edges.n_edges)} for f, m in maps.items()}
    blob = {"format": DECISIONS_FORMAT, "map_seed": MAP_SEED, "first_seed": FIRST_SEED, "maps": meta, "seeds": seeds,
            "seconds": took, "workers": workers, "decisions": decisions}  # fmt: skip
    with atomic_path(path) as tmp, gzip.open(tmp, "wb", compresslevel=6) as fh:
        pickle.dump(blob, fh, protocol=pickle.HIGHEST_PROTOCOL)


def load_decisions(path: str | os.PathLike) -> dict:
    """What `save_decisions` wrote (keys format, map_seed, first_seed, maps, seeds, seconds, workers,
    decisions); ConfigError for any other file.  Pickle runs code as it reads: load only
    files you made."""
    try:
        with gzip.open(path, "rb") as fh:
            blob = pickle.load(fh)
    except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError) as e:
        raise ConfigError(f"{path}: not a decisions file ({e})") from None
    if not isinstance(blob, dict) or blob.get("format") != DECISIONS_FORMAT:
        raise ConfigError(f"{path}: not a decisions file of {DECISIONS_FORMAT}")
    if blob["map_seed"] != MAP_SEED or blob["first_seed"] != FIRST_SEED:
        raise ConfigError(f"{path}: decisions of map seed {blob['map_seed']} from trial seed {blob['first_seed']}, "
                          f"not the test's {MAP_SEED} and {FIRST_SEED}: build them again")  # fmt: skip
    return blob


def passes(report: dict) -> bool:
    """Whether an `out_of_sample` report meets the test's pass (see MAP_SEED's comment)."""
    return bool(
        report["decisions"] >= MIN_DECISIONS
        and report["non_finite"] == 0
        and report["target_end_diff_m"]["median"] <= MAX_MEDIAN_END_DIFF
        and report["same_or_within_1cm"] >= MIN_SAME_OR_NEAR
    )
