"""The edge planner with simulation in the loop (paper Algorithm 3).

Each step: observe the scene; take the edges of the map whose interaction point passes over
the target (the map's spatial index, over the cells the target covers); turn an edge into an
action (transit from the robot's current configuration to the edge's start, then the edge);
choose one by the action selection mechanism (ASM):
  * random: uniformly among the edges over the target, no simulation;
  * lazy:   edges in random order, simulated one by one (from the observed state); the first
            that moves the target toward the goal is taken (if none within `lazy_tries`, the
            best simulated one);
  * greedy: a uniform subset of `greedy_candidates` edges simulated in one batch; the one
            that leaves the target closest to the goal (with a penalty for every object that
            leaves the table) is taken; by default its `rescore_top` best are first simulated
            again from redrawn observations (`drawn_starts`), the best mean taken.
"Closest" is the path length around the fixed obstacles (`GoalField`; the plain distance
where nothing is in the way).  An edge that was executed and did not bring the target closer
is not offered again while the target stays where it was (the simulator was wrong about it
once; trying it again would waste the action budget).
Execute it in the "real" world, observe, repeat until the target is in the goal region or
the budget (actions; the planning limit, counted in simulated control steps) is spent.
Actions whose transit would hit the table or the arm itself are skipped.  Everything random
comes from the trial's seed.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Generator
from typing import Any, TypeVar

import numpy as np

from lmjx.mapfile.bundle import Bundle
from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.planner.phases import PhaseClock
from lmjx.planner.records import StepRecord, TrialResult
from lmjx.planner.requests import Execute, Executed, Request, Simulate, Simulated
from lmjx.planner.scoring import (
    OFF_TABLE_PENALTY,
    TARGET_LOST,
    _finite_m,
    _score_field,
    drawn_starts,
    goal_distance,
    score,
)
from lmjx.planner.search import NO_ACTION_KEYS
from lmjx.planner.transit import TransitPlanner, after_executing
from lmjx.planner.turned import TurnAxis, TurnedEdges, turn_axis, turned_over_target
from lmjx.reach.reachability import ReachResult
from lmjx.runtime.compiletime import compile_seconds, jax_compile_seconds
from lmjx.sim.scenarios import Layout, Scenario, in_goal
from lmjx.types import OPTIONS_NEAR, Action, Executor, Observation, PlannerConfig, Simulator

T = TypeVar("T")


def edges_over_target(
    bundle: Bundle, reach: ReachResult, target_xy: np.ndarray, half: float, margin: float
) -> np.ndarray:
    """Edges whose point passes over any reach cell within half + margin of the target's centre."""
    cell = reach.config.cell
    xs, ys = reach.xs, reach.ys
    r = half + margin
    ix = np.nonzero(np.abs(xs - target_xy[0]) <= r + cell / 2)[0]
    iy = np.nonzero(np.abs(ys - target_xy[1]) <= r + cell / 2)[0]
    nx = len(xs)
    found = [bundle.edges_over(int(y), int(x), nx) for y in iy for x in ix]
    if not found:
        return np.zeros(0, np.int32)
    ids = np.sort(np.concatenate(found))
    return ids[np.r_[True, ids[1:] != ids[:-1]]] if len(ids) else ids


def _degrees(turn: float) -> int:
    """A turn [rad] in whole degrees (turns are whole degrees: `lmjx.planner.turned`)."""
    return round(math.degrees(turn))


def simulate_request(sim: Simulator, req: Simulate) -> Simulated:
    c0, t0 = compile_seconds(sim), time.perf_counter()
    final = np.concatenate(sim.simulate_many(req.parts()))
    wall, compiled = time.perf_counter() - t0, compile_seconds(sim) - c0
    return Simulated(final, max(0.0, wall - compiled), compiled)


def execute_request(executor: Executor, req: Execute) -> Executed:
    t0 = time.perf_counter()
    obs = executor.execute(req.action)
    return Executed(obs, time.perf_counter() - t0)


def drive(steps: Generator[Request, Any, T], sim: Simulator | None, executor: Executor | None = None) -> T:
    """Run a planner's generator to its end, answering each request at once."""
    answer: Any = None
    while True:
        try:
            req = steps.send(answer)
        except StopIteration as done:
            return done.value
        if isinstance(req, Simulate):
            assert sim is not None, "this planner simulates: give it a simulator"
            answer = simulate_request(sim, req)
        else:
            assert executor is not None
            answer = execute_request(executor, req)


class Planner:
    """Algorithm 3 for one failure's map and one scenario.

    The planner is written as generators that *ask* for simulations and executions
    (`Simulate`, `Execute`) and are answered by whoever drives them: `run` answers one
    trial's requests as they come; `lmjx.evaluation.lockstep` answers many trials' requests together,
    so that a GPU simulates the candidates of all of them in one batch.  Either way a trial
    makes the same decisions.  With a simulator that prefers batches (`prefers_batches`),
    Lazy simulates its tries in one batch and takes the first improvement in their order:
    the choice the one-by-one search makes, simulated at once.
    """

    def __init__(
        self,
        robot: Robot,
        failure: Failure,
        reach: ReachResult,
        bundle: Bundle,
        sc: Scenario,
        simulator: Simulator | None,
        config: PlannerConfig,
        transits: TransitPlanner | None = None,
    ) -> None:
        config.validate()
        self.robot = robot
        self.failure = failure
        self._axis: TurnAxis | None = None  # the base joint turned edges turn about (`turn_axis`, found once)
        self.reach = reach
        self.bundle = bundle
        self.sc = sc
        self.sim = simulator
        self.config = config
        batched = bool(getattr(simulator, "prefers_batches", False))
        self.batched = batched
        bundle.hold(("q",))  # (a lazily read map: each decision screens the states of thousands of edges)
        self.transits = transits or TransitPlanner(robot, failure, batched=batched)
        self.transits.late_start = config.late_start  # (trials sharing a TransitPlanner share a config)
        self.field = _score_field(robot, failure, reach, bundle, sc, config)
        # edges that were executed here and did not move the target toward the goal: target
        # position at the time, per edge (not offered again while the target stays there)
        self.futile: dict[tuple[int, int], np.ndarray] = {}  # keyed by (map edge, turn in degrees)
        self.came_from: np.ndarray | None = None  # the last executed edge's states (transits retreat along it)
        self.trail: np.ndarray | None = None  # every joint target the arm followed in this trial (the way back)
        # rescoring's draws (`PlannerConfig.rescore_top`): a stream of their own, seeded by the
        # trial, so that the trial's other random choices are those it makes without them
        self.draws = np.random.default_rng(0)
        self.clock = PhaseClock()  # where each decision's time goes (`StepRecord.phase_s`)
        # told after each executed action: (its number, the action budget, its record)
        self.on_action: Callable[[int, int, StepRecord], None] | None = None

    def choose(self, obs: Observation, rng: np.random.Generator) -> tuple[Action | None, StepRecord]:
        """One decision, simulating on this planner's simulator, timed as a trial times it
        (`_timed_decision`: its planning time leaves out what was compiled meanwhile,
        `StepRecord.compile_s`)."""
        return drive(self._timed_decision(obs, rng), self.sim)

    def decide(self, obs: Observation, rng: np.random.Generator) -> Generator[Simulate, Simulated, tuple]:
        """One decision: yields the simulations it needs; returns (action or None, record)."""
        cfg = self.config
        clock = self.clock
        target = obs.objects[0, :2]
        with clock.phase("offer"):
            self.transits.set_scene(self.sc, obs.objects)
            half = float(self.sc.target.half[0])
            edges = edges_over_target(self.bundle, self.reach, target, half, cfg.target_margin)
            if cfg.futile_filter and self.futile:
                edges = edges[~self._futile_here(edges, np.zeros(len(edges), np.int64), target)]
            order = rng.permutation(edges)
            bundle: Any = self.bundle
            if cfg.turn_edges:  # the map's own edges first, then turned copies (`lmjx.planner.turned`)
                bundle, order = self._with_turned(order, target, half, rng)
            now = float(self.field(target))
        rec = StepRecord(-1, len(order), 0, None, float(goal_distance(self.sc, target)), 0.0, 0.0)
        if cfg.asm == "random":
            acts = self.transits.actions(bundle, order, obs.robot_q, 1, self.came_from, self.trail, clock)
            if acts:
                rec.edge, rec.turn_deg = acts[0].edge, _degrees(acts[0].turn)
            else:
                rec.no_action = dict(self.transits.last_tally)
            return (acts[0] if acts else None), rec
        if cfg.asm == "greedy":
            want = cfg.greedy_candidates
            if cfg.greedy_fraction is not None:
                want = max(1, math.ceil(cfg.greedy_fraction * len(order)))
            acts = self.transits.actions(bundle, order, obs.robot_q, want, self.came_from, self.trail, clock)
            if not acts:
                rec.no_action = dict(self.transits.last_tally)
                return None, rec
            done = yield Simulate(obs.robot_q, obs.objects, acts)
            with clock.phase("simulate"):
                s = score(self.sc, self.robot, done.objects, self.field)
                chosen_by = s  # what Greedy's choice (`best_of`) minimises
                rescoring = cfg.rescore_top > 0 and len(acts) > 1
            if rescoring:
                with clock.phase("rescore"):
                    top = np.argsort(s, kind="stable")[: cfg.rescore_top]
                    resting = np.array([b.zc for b in self.sc.movable])
                    starts = drawn_starts(obs.objects, cfg.rescore_draws - 1, self.draws, resting)
                more = yield Simulate(obs.robot_q, starts, [acts[int(i)] for i in top], phase="rescore")
                with clock.phase("rescore"):
                    drawn = score(self.sc, self.robot, more.objects, self.field).reshape(len(starts), len(top))
                    mean = (s[top] + drawn.sum(axis=0)) / (len(starts) + 1)
                    chosen_by = np.full(len(s), np.inf)  # only the rescored candidates, by their mean
                    chosen_by[top] = np.where(np.isnan(mean), np.inf, mean)  # (a rollout gone non-finite loses)
            best = self.best_of(chosen_by, rng)
            if rescoring:
                rec.rescored = {
                    "mean_m": _finite_m(chosen_by[best]),
                    "first_mean_m": _finite_m(chosen_by[top[0]]),
                    "changed": bool(best != top[0]),
                }
            if cfg.when_stuck == "options" and float(s[best]) > now - cfg.min_progress:
                rescored_pick = best
                with clock.phase("simulate"):
                    best, rec.stuck = self._most_options(done.objects, s)
                    self.transits.set_scene(self.sc, obs.objects)  # the observed scene again
                if rec.rescored is not None and best != rescored_pick:
                    rec.rescored["overridden"] = True  # the rule when stuck took another candidate
            rec.simulated = len(acts)
            rec.predicted_distance = float(s[best])
            rec.edge, rec.turn_deg = acts[best].edge, _degrees(acts[best].turn)
            return acts[best], rec
        # lazy: in random order, the first that brings the target closer wins
        best_a, best_s = None, np.inf
        tries = cfg.lazy_tries if cfg.lazy_cap else len(order)
        improved = False
        if self.batched:  # its tries at once, then the first improvement in their order
            acts = self.transits.actions(bundle, order, obs.robot_q, tries, self.came_from, self.trail, clock)
            rec.simulated = len(acts)
            if acts:
                done = yield Simulate(obs.robot_q, obs.objects, acts)
                with clock.phase("simulate"):
                    for a, sc in zip(acts, score(self.sc, self.robot, done.objects, self.field), strict=True):
                        if float(sc) < best_s:
                            best_a, best_s = a, float(sc)
                        if sc <= now - cfg.min_progress:
                            improved = True
                            break
            else:
                rec.no_action = dict(self.transits.last_tally)
        elif not cfg.late_start:  # one at a time, stopping at the first improvement
            search = self.transits.search_actions(bundle, order, obs.robot_q, self.came_from, self.trail, clock)
            while rec.simulated < tries:
                with clock.phase("offer"):
                    self.transits.set_scene(self.sc, obs.objects)  # (a transit planner shared while waiting)
                acts = search.next(1, grow=False)  # the next edge in order that has an action
                if not acts:
                    break
                rec.simulated += 1
                done = yield Simulate(obs.robot_q, obs.objects, acts)
                with clock.phase("simulate"):
                    sc = float(score(self.sc, self.robot, done.objects, self.field)[0])
                if sc < best_s:
                    best_a, best_s = acts[0], sc
                if sc <= now - cfg.min_progress:
                    improved = True
                    break
            if rec.simulated == 0:
                rec.no_action = dict(search.tally)
        else:  # one at a time, each edge searched alone (late starts are tried edge by edge)
            tally = dict.fromkeys(NO_ACTION_KEYS, 0)
            for e in order:
                if rec.simulated == tries:
                    break
                with clock.phase("offer"):
                    self.transits.set_scene(self.sc, obs.objects)  # again: trials run together share `transits`
                acts = self.transits.actions(bundle, np.array([e]), obs.robot_q, 1, self.came_from, self.trail, clock)
                for k, v in self.transits.last_tally.items():
                    tally[k] += v
                if not acts:
                    continue
                rec.simulated += 1
                done = yield Simulate(obs.robot_q, obs.objects, acts)
                with clock.phase("simulate"):
                    sc = float(score(self.sc, self.robot, done.objects, self.field)[0])
                if sc < best_s:
                    best_a, best_s = acts[0], sc
                if sc <= now - cfg.min_progress:
                    improved = True
                    break
            if rec.simulated == 0:
                rec.no_action = tally
        if not (improved or cfg.lazy_fallback):
            best_a = None
        if best_a is not None:
            rec.edge, rec.turn_deg = best_a.edge, _degrees(best_a.turn)
            rec.predicted_distance = best_s
        return best_a, rec

    @staticmethod
    def best_of(scores: np.ndarray, rng: np.random.Generator) -> int:
        """Greedy's choice among its simulated candidates: the lowest score."""
        return int(np.argmin(scores))

    def _most_options(self, predicted: np.ndarray, scores: np.ndarray) -> tuple[int, dict]:
        """Greedy stuck (no candidate predicted to improve), when_stuck="options": of the
        candidates that keep every object on the table (else all), the one whose predicted
        state (`predicted`, (n, k, 7)) leaves the most edges to offer, by
        `TransitPlanner.options`; the best predicted of those within OPTIONS_NEAR of the most.
        Returns its index and what the record keeps."""
        keep = np.nonzero(scores < OFF_TABLE_PENALTY)[0]
        if not len(keep):
            keep = np.arange(len(scores))
        half = float(self.sc.target.half[0])
        opts = np.zeros(len(scores))
        for i in keep:
            target = predicted[i, 0, :2]
            edges = edges_over_target(self.bundle, self.reach, target, half, self.config.target_margin)
            self.transits.set_scene(self.sc, predicted[i])
            # the same sample of a state's edges whoever asks (the trial's rng is left alone)
            opts[i] = self.transits.options(self.bundle, edges, np.random.default_rng(len(edges)))
        near = keep[opts[keep] >= OPTIONS_NEAR * opts[keep].max()]
        best = int(near[np.argmin(scores[near])])
        rec = {
            "options": round(float(opts[best]), 1),
            "most_options": round(float(opts[keep].max()), 1),
            "predicted_m": round(float(scores[best]), 4),
            "best_predicted_m": round(float(scores.min()), 4),
        }
        return best, rec

    def _with_turned(
        self, order: np.ndarray, target: np.ndarray, half: float, rng: np.random.Generator
    ) -> tuple[TurnedEdges | Bundle, np.ndarray]:
        """`order` (the map's edges over the target) followed by the turned copies of the map's
        edges over it (`turned_over_target`, those found futile here left out) in random order,
        as a view the transit planner takes in the bundle's place, and the view's candidates in
        that order; the bundle and `order` where there are none."""
        ids, delta = turned_over_target(
            self.bundle, self.reach, self.robot, self.failure, target, half, self.config.target_margin
        )
        if self.config.futile_filter and self.futile and len(ids):
            keep = ~self._futile_here(ids, np.round(np.degrees(delta)).astype(np.int64), target)
            ids, delta = ids[keep], delta[keep]
        if not len(ids):
            return self.bundle, order
        axis = turn_axis(self.robot, self.failure) if self._axis is None else self._axis
        assert axis is not None  # (turned copies exist only about one)
        self._axis = axis
        mixed = rng.permutation(len(ids))
        view = TurnedEdges(
            self.bundle,
            np.concatenate([np.asarray(order, np.int64), ids[mixed]]),
            np.concatenate([np.zeros(len(order)), delta[mixed]]),
            axis,
        )
        return view, np.arange(view.n_edges)

    def _futile_here(self, edges: np.ndarray, turns_deg: np.ndarray, target: np.ndarray) -> np.ndarray:
        """(len(edges),) whether each (map edge, turn in whole degrees) was executed here
        (the target within `futile_radius` of where it was then) without bringing it closer."""
        out = np.zeros(len(edges), bool)
        near = [k for k, at in self.futile.items() if float(np.hypot(*(target - at))) < self.config.futile_radius]
        if near:
            span = 1 << 12  # (turns are whole degrees, |turn| < 2048)
            keys = np.asarray(edges, np.int64) * span + np.asarray(turns_deg, np.int64) + span // 2
            out = np.isin(keys, [e * span + t + span // 2 for e, t in near])
        return out

    def run(self, executor: Executor, layout: Layout, seed: int) -> TrialResult:
        """One closed-loop trial, simulating and executing each request as it comes."""
        return drive(self.trial(executor, layout, seed), self.sim, executor)

    def trial(self, executor: Executor, layout: Layout, seed: int) -> Generator[Request, Any, TrialResult]:
        """One closed-loop trial as a generator of requests (see the class docstring).  A
        decision's planning time is its own computation plus the simulation seconds its
        driver charges it."""
        cfg = self.config
        rng = np.random.default_rng(seed)
        self.draws = np.random.default_rng([seed, 1])
        self.futile = {}
        self.came_from = None
        obs = executor.reset(layout, self.transits.park)
        self.trail = obs.robot_q[None].copy()
        steps: list[StepRecord] = []
        planning = 0.0
        simulated = 0  # control steps simulated: the planning limit's count (host-independent)
        reason = "budget"
        budget = cfg.max_actions or self.sc.budget
        for _ in range(budget):
            if in_goal(self.sc, obs.objects[0, :2], cfg.goal_margin):
                reason = "goal"
                break
            if simulated >= cfg.max_sim_steps:
                reason = "planning limit"
                break
            action, rec = yield from self._timed_decision(obs, rng)
            planning += rec.planning_s
            simulated += rec.sim_steps
            if action is None:
                # edges were tested and none offered: for want of a transit, or (none of them
                # lacking one) their starts blocked or the edges unusable here
                reason = "no feasible transit"
                if rec.no_action is not None and not rec.no_action.get("no_transit", 0):
                    reason = "no feasible action"
                if rec.candidates == 0:
                    reason = "no edge over the target"
                elif rec.simulated > 0:
                    reason = "no edge moves the target"
                steps.append(rec)
                break
            t_before = obs.time
            before = obs.objects[0, :2].copy()
            executed = yield Execute(action)
            obs = executed.observation
            rec.phase_s["execute"] = round(executed.seconds, 4)
            self.came_from, self.trail = after_executing(action, self.trail, self.bundle.q_start.dtype)
            closer = float(self.field(obs.objects[0, :2])) <= float(self.field(before)) - cfg.min_progress
            if cfg.futile_filter and not closer:
                self.futile[(action.edge, _degrees(action.turn))] = before
            rec.execution_s = obs.time - t_before
            rec.distance_after = float(goal_distance(self.sc, obs.objects[0, :2]))
            rec.target_moved_m = obs.target_moved_m
            rec.transit_contacts = obs.transit_contacts
            rec.transit_hit_fixed = obs.transit_hit_fixed
            rec.transit_left = obs.transit_left
            rec.transit_route = action.route
            rec.edge_states = action.edge_states
            rec.edge_first = action.edge_first
            rec.score_after = float(score(self.sc, self.robot, obs.objects[None], self.field)[0])
            steps.append(rec)
            if self.on_action is not None:
                self.on_action(sum(1 for s in steps if s.edge >= 0), budget, rec)
            if rec.score_after >= TARGET_LOST:
                reason = "target off the table"
                break
        else:
            if in_goal(self.sc, obs.objects[0, :2], cfg.goal_margin):
                reason = "goal"
        truth = executor.truth()
        success = in_goal(self.sc, truth[0, :2]) and truth[0, 2] > -0.02
        return TrialResult(
            success=bool(success),
            actions=sum(1 for s in steps if s.edge >= 0),
            planning_s=planning,
            compile_s=sum(s.compile_s for s in steps),
            sim_steps=simulated,
            execution_s=obs.time,
            final_distance=float(goal_distance(self.sc, truth[0, :2])),
            steps=steps,
            reason="goal" if success else reason,
            stopped=reason,
        )

    def _timed_decision(self, obs: Observation, rng: np.random.Generator):
        """`decide`, timed: its latency (`StepRecord.latency_s`: its own computation and the
        wall time of the simulations it waited for, each less what was compiled meanwhile,
        which is counted apart in `compile_s`), where that time went (`phase_s`, by
        `PhaseClock`), the part of its simulations' time spent on other trials' candidates
        sharing their batches (`shared_s`), and the control steps its simulations rolled out
        (`sim_steps`)."""
        self.clock.reset()
        steps = self.decide(obs, rng)
        own, waited, shared, compiled, simulated = 0.0, 0.0, 0.0, 0.0, 0
        answer = None
        while True:
            c0, t0 = jax_compile_seconds(), time.perf_counter()
            try:
                req = steps.send(answer)
            except StopIteration as done:
                c = jax_compile_seconds() - c0
                own += time.perf_counter() - t0 - c
                action, rec = done.value
                self.clock.seconds["compile"] = compiled + c  # (the phases' own count is part of this)
                rec.compile_s = compiled + c
                rec.latency_s = rec.planning_s = max(0.0, own + waited)
                rec.simulation_s = waited
                rec.shared_s = shared
                rec.phase_s = self.clock.rounded()
                rec.sim_steps = simulated
                return action, rec
            c = jax_compile_seconds() - c0
            own += time.perf_counter() - t0 - c
            compiled += c
            simulated += req.control_steps
            answer = yield req
            waited += answer.seconds
            shared += answer.shared_s
            compiled += answer.compile_s
            self.clock.add(req.phase, answer.seconds)
