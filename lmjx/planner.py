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
the budget (actions, planning time) is spent.  Actions whose transit would hit the table or
the arm itself are skipped.  Everything random comes from the trial's seed.
"""

from __future__ import annotations

import math
import time
from collections.abc import Generator
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar

import numpy as np

from .actions import NO_ACTION_KEYS, Action, TransitPlanner, after_executing
from .bundle import Bundle
from .compiletime import compile_seconds, jax_compile_seconds
from .errors import ConfigError
from .executor import Executor, Observation
from .failure import Failure
from .goalfield import GoalField
from .reach import ReachResult
from .reprs import config_repr
from .robot import Robot
from .scenarios import Layout, Scenario, in_goal
from .simulate import Simulator

T = TypeVar("T")
ASMS = ("random", "lazy", "greedy")
OFF_TABLE_PENALTY = 1.0  # [m] per object that leaves the table
TARGET_LOST = 10.0  # [m] when the target leaves the table
WHEN_STUCK = ("best", "options")
SERVOS = ("playback", "robot")  # the planner simulator's servo models (`PlannerConfig.servo`)
# rescoring's draws of the observed poses: the "real" world's observation noise
# (`executor.SimulatedRealWorld`: x, y each N(0, 2 mm), yaw N(0, 1.5 deg))
RESCORE_POS_NOISE = 0.002  # [m]
RESCORE_YAW_NOISE = math.radians(1.5)  # [rad]
OPTIONS_NEAR = 0.8  # when_stuck="options": candidates with at least this share of the most options qualify


@dataclass(frozen=True)
class PlannerConfig:
    asm: str = "greedy"
    max_actions: int | None = None  # the action budget; None: the task set's (`Scenario.budget`)
    max_planning_s: float = 600.0
    greedy_candidates: int = 32
    lazy_tries: int = 32
    min_progress: float = 0.005  # "moved toward the goal": the distance drops by at least this [m]
    target_margin: float = 0.01  # edges over cells within the target's half size + this [m]
    goal_margin: float = 0.01  # stop once the observed target is this far inside the goal region [m]
    futile_radius: float = 0.01  # an executed edge that made no progress is not offered again
    # while the target stays within this distance of where it was [m]
    # lmjx's refinements of the paper's ASMs, each of which can be turned off (`paper()`):
    futile_filter: bool = True  # edges that failed here are not offered again (futile_radius)
    path_score: bool = True  # "closest" = path length around the fixed obstacles (else straight distance)
    lazy_fallback: bool = True  # Lazy takes its best simulated edge when none brings the target closer
    lazy_cap: bool = True  # Lazy stops after lazy_tries simulations (the paper: no cap)
    greedy_fraction: float | None = None  # Greedy's subset: this fraction of the edges over the
    # target (at least one) instead of greedy_candidates
    when_stuck: str = "best"  # Greedy when no candidate is predicted to bring the target min_progress
    # closer: "best" takes the best predicted all the same (the paper's Greedy); "options" takes,
    # among the candidates that keep every object on the table, the one whose predicted state
    # leaves the most edges to offer (starts clear, acting on the target: `TransitPlanner.options`),
    # the best predicted of those within OPTIONS_NEAR of the most
    late_start: bool = False  # where the edges with clear starts give fewer candidates than
    # wanted, an edge whose start lies within a fixed obstacle's margin is offered from its first
    # state clear of the scene (`TransitPlanner.late_starts`), where that part still acts on the
    # target; off: such an edge is not offered
    push_weight: float = 1.0  # > 0: "closest" is the cost of the cheapest way to the goal, each
    # metre weighted by how rarely the map's edges push toward the goal there (`lmjx.pushfield`:
    # 1 + push_weight * ln(median / pushes), at least 1); 0: the path length (`path_score`).
    # 1 since 2026-11-27 (benchmarks/evaluation_plan_2026-11-27.md; 0 before)
    rescore_top: int = 8  # > 0: Greedy simulates its this many best candidates again from
    # rescore_draws - 1 more starts, every object's observed pose redrawn with the observation
    # noise the "real" world's camera has (`RESCORE_POS_NOISE`, `RESCORE_YAW_NOISE`), and takes
    # the one with the lowest mean score over the rescore_draws starts (the observed one
    # included): a push whose outcome hangs on millimetres no longer wins on one lucky rollout.
    # 8 since 2026-11-27 (0 before: benchmarks/evaluation_plan_2026-11-28.md, the fourteenth
    # session's rule); 0: off
    rescore_draws: int = 8
    servo: str = "robot"  # the planner's simulator tracks the arm's joint targets with "robot":
    # the robot's own joint servo gains and torque limits (`executor.real_gains`: the controller
    # the arm runs, so a simulated push lags and overshoots as the arm's does), or "playback":
    # stiff servos with unlimited torque (near-exact playback of the trajectory).  "robot" since
    # 2026-11-27 (playback before: benchmarks/evaluation_plan_2026-11-28.md, the sixteenth
    # session's rule)

    __repr__ = config_repr

    def validate(self) -> None:
        if self.asm not in ASMS:
            raise ConfigError(f"unknown action selection mechanism '{self.asm}'; use random, lazy or greedy")
        if (self.max_actions is not None and self.max_actions < 1) or self.greedy_candidates < 1 or self.lazy_tries < 1:
            raise ConfigError("max_actions, greedy_candidates and lazy_tries must be positive")
        if self.greedy_fraction is not None and not 0.0 < self.greedy_fraction <= 1.0:
            raise ConfigError(f"greedy fraction {self.greedy_fraction:g} must lie in (0, 1]")
        if not (math.isfinite(self.push_weight) and self.push_weight >= 0.0):
            raise ConfigError(f"push weight {self.push_weight:g} must be a number at least 0")
        if self.push_weight > 0.0 and not self.path_score:
            raise ConfigError(
                "a push weight weighs the path-length score, which the paper's ASM settings replace by the "
                "straight distance: leave out --push-weight or --asm-settings paper"
            )
        if self.rescore_top < 0:
            raise ConfigError(f"the candidates to rescore must be at least 0, got {self.rescore_top}")
        if self.rescore_draws < 2:
            raise ConfigError(f"rescoring needs at least 2 starts a candidate (the observed one and a draw), got "
                              f"{self.rescore_draws}")  # fmt: skip
        if self.when_stuck not in WHEN_STUCK:
            raise ConfigError(f"unknown rule when stuck '{self.when_stuck}'; use {' or '.join(WHEN_STUCK)}")
        if self.servo not in SERVOS:
            raise ConfigError(f"unknown servo model '{self.servo}'; use {' or '.join(SERVOS)}")

    def paper(self) -> PlannerConfig:
        """The ASMs as the paper states them (Algorithm 3): no futile-edge filter, the straight
        distance to the goal, Lazy over all the edges over the target in random order with no
        fallback (when none moves the target toward the goal: no action), Greedy on a uniform
        subset of a quarter of them (no push weight: it weighs the path length, not used; no
        rescoring: the paper's Greedy takes its best simulated candidate)."""
        return replace(self, futile_filter=False, path_score=False, lazy_fallback=False, lazy_cap=False,
                       greedy_fraction=0.25, push_weight=0.0, rescore_top=0)  # fmt: skip

    def settings(self, asm: str | None = None) -> dict:
        """The refinements on or off, for the records of `asm` (default: this config's)."""
        greedy = f"{self.greedy_candidates} candidates"
        if self.greedy_fraction is not None:
            greedy = f"{self.greedy_fraction:g} of the edges over the target"
        return {
            "futile_filter": self.futile_filter,
            "path_score": self.path_score,
            "lazy_fallback": self.lazy_fallback,
            "lazy_tries": self.lazy_tries if self.lazy_cap else None,
            "greedy_subset": greedy,
            "when_stuck": self.when_stuck,
            "late_start": self.late_start,
            "push_weight": self.push_weight,
            # (only Greedy's, and only when on: the records of runs before it existed read the same)
            **(
                {"rescore": f"best {self.rescore_top}, {self.rescore_draws} starts"}
                if self.rescore_top and (asm or self.asm) == "greedy"
                else {}
            ),
            # (only where not the playback, the only model before this setting existed, and only
            # for the ASMs that simulate: as above)
            **({"servo": self.servo} if self.servo != "playback" and (asm or self.asm) != "random" else {}),
        }


@dataclass
class StepRecord:
    edge: int
    candidates: int
    simulated: int
    predicted_distance: float | None
    distance_after: float
    planning_s: float
    execution_s: float
    # what the executed action did in the "real" world (Observation's report)
    target_moved_m: float = float("nan")
    transit_contacts: tuple[str, ...] = ()
    transit_hit_fixed: bool = False
    transit_left: tuple[str, ...] = ()
    transit_route: str = ""  # "direct", "park" or "roadmap", after an escape "escape+..." (`Action.route`)
    edge_states: int = -1  # the edge's states executed (`Action.edge_states`: fewer where a fixed obstacle cut it)
    edge_first: int = 0  # the edge's first state executed (`Action.edge_first`: > 0 only with late_start)
    compile_s: float = 0.0  # seconds of compilation during the decision, not in planning_s (`lmjx.compiletime`)
    simulation_s: float = 0.0  # of planning_s, the seconds its simulations were charged (not in the records)
    # a decision that found no action: the edges over the target it tested, by why none was
    # offered (`TransitPlanner.actions`' tally, `NO_ACTION_KEYS`)
    no_action: dict | None = None
    # the planner's score (`score`: the path length to the goal, weighted with a push weight,
    # plus penalties) of the observed state after the action; beside `predicted_distance`, the
    # same score of the chosen candidate's simulated outcome (Greedy, Lazy), what the planner
    # expected: the two apart are the planner's simulator against the "real" world
    score_after: float = float("nan")
    # Greedy with when_stuck="options" at a decision where no candidate was predicted to
    # improve: the chosen candidate's estimated options and predicted score, and the best
    # predicted score (`Planner._most_options`)
    stuck: dict | None = None
    # Greedy with rescore_top: the chosen candidate's mean score over the draws, the best
    # candidate's by the observed start alone, and whether the rescoring changed the choice
    rescored: dict | None = None

    def __repr__(self) -> str:
        moved = "" if np.isnan(self.target_moved_m) else f", target moved {self.target_moved_m * 100:.1f} cm"
        return (
            f"StepRecord(edge {self.edge} of {self.candidates} candidates, {self.simulated} simulated; "
            f"{self.distance_after * 100:.1f} cm from the goal after{moved}; transit {self.transit_route or '-'})"
        )

    def summary(self) -> dict:
        return {
            "edge": self.edge,
            "candidates": self.candidates,
            "simulated": self.simulated,
            "distance_after_m": round(self.distance_after, 4),
            "planning_s": round(self.planning_s, 3),
            "target_moved_m": None if np.isnan(self.target_moved_m) else round(self.target_moved_m, 4),
            "predicted_score_m": None if self.predicted_distance is None else round(self.predicted_distance, 4),
            "score_after_m": None if np.isnan(self.score_after) else round(self.score_after, 4),
            "transit_contacts": list(self.transit_contacts),
            "transit_hit_fixed": self.transit_hit_fixed,
            "transit_left": list(self.transit_left),
            "transit_route": self.transit_route,
            "edge_states": self.edge_states,
            **({"edge_first": self.edge_first} if self.edge_first else {}),
            **({"compile_s": round(self.compile_s, 3)} if self.compile_s >= 0.0005 else {}),
            **({"no_action": self.no_action} if self.no_action is not None else {}),
            **({"stuck": self.stuck} if self.stuck is not None else {}),
            **({"rescored": self.rescored} if self.rescored is not None else {}),
        }


ENDS = ("goal", "budget", "planning time", "no edge over the target", "no feasible transit", "no edge moves the target",
        "target off the table")  # fmt: skip


@dataclass
class TrialResult:
    success: bool
    actions: int
    planning_s: float
    execution_s: float
    final_distance: float
    steps: list[StepRecord] = field(default_factory=list)
    reason: str = ""  # how the trial ended: "goal" whenever the target ends in the goal (success)
    compile_s: float = 0.0  # seconds its decisions spent compiling (not in planning_s; `lmjx.compiletime`)
    stopped: str = ""  # what stopped the planner (one of ENDS): it stops once the observed target
    # is `goal_margin` inside the goal, so a target that ended in the goal but nearer its edge
    # shows here what came next (e.g. "no feasible transit")

    def __repr__(self) -> str:
        end = "success" if self.success else "failure"
        return (
            f"TrialResult({end} ({self.reason}) after {self.actions} actions; planning {self.planning_s:.1f} s, "
            f"robot time {self.execution_s:.1f} s; target {self.final_distance * 100:.1f} cm from the goal's centre)"
        )

    def summary(self) -> dict:
        return {
            "success": self.success,
            "actions": self.actions,
            "planning_s": round(self.planning_s, 3),
            "compile_s": round(self.compile_s, 3),
            "execution_s": round(self.execution_s, 3),
            "final_distance_m": round(self.final_distance, 4),
            "end": self.reason,
            "stopped": self.stopped or self.reason,
        }

    def action_records(self) -> list[dict]:
        """Per executed action: what it did (see `StepRecord.summary`)."""
        return [s.summary() for s in self.steps if s.edge >= 0]


class _Straight:
    """The straight distance to the goal's centre (the paper's score), called as a GoalField."""

    def __init__(self, sc: Scenario) -> None:
        self.sc = sc

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        return goal_distance(self.sc, np.asarray(xy))


def _score_field(
    robot: Robot, failure: Failure, reach: ReachResult, bundle: Bundle, sc: Scenario, cfg: PlannerConfig
) -> GoalField | _Straight:
    """What Greedy and Lazy call "closest" (`PlannerConfig.path_score`, `push_weight`)."""
    if not cfg.path_score:
        return _Straight(sc)
    lo, hi = table_bounds(robot)
    if cfg.push_weight <= 0.0 or cfg.asm == "random":  # (Random scores nothing: no counts for it)
        return GoalField(sc, lo, hi)
    from .pushfield import bundle_memo, cached_counts, counts_key, push_counts, push_pairs, push_weights

    memo = bundle_memo(bundle)  # the weighted field, once per bundle, scenario and weight
    key = ("field", sc, cfg.push_weight, cfg.target_margin)
    if key not in memo:
        plain = GoalField(sc, lo, hi)
        counts, _ = cached_counts(
            counts_key(robot, bundle, reach, sc, plain),
            reach.labels.shape,
            lambda: push_counts(push_pairs(robot, failure, bundle, reach, sc, plain, progress=True)[0], reach),
        )
        radius = float(sc.target.half[0]) + cfg.target_margin
        memo[key] = GoalField(sc, lo, hi, weights=push_weights(counts, reach, radius, cfg.push_weight))
    return memo[key]


def goal_distance(sc: Scenario, xy: np.ndarray) -> np.ndarray:
    """Distance (...,) from points (..., 2) to the goal region's centre."""
    return np.hypot(xy[..., 0] - sc.goal_center[0], xy[..., 1] - sc.goal_center[1])


def table_bounds(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    arm = robot.arm
    return arm.table_center[:2] - arm.table_half[:2], arm.table_center[:2] + arm.table_half[:2]


def score(sc: Scenario, robot: Robot, objects: np.ndarray, field: GoalField | None = None) -> np.ndarray:
    """Lower is better: the target's path length to the goal around the fixed obstacles
    (`GoalField`), plus penalties for objects that leave the table.  objects: (..., n, 7)."""
    lo, hi = table_bounds(robot)
    field = field or GoalField(sc, lo, hi)
    xy = objects[..., :2]
    off = (objects[..., 2] < robot.arm.table_z - 0.02) | np.any((xy < lo) | (xy > hi), axis=-1)
    s = field(objects[..., 0, :2])
    s = s + OFF_TABLE_PENALTY * off[..., 1:].sum(axis=-1)
    return np.where(off[..., 0], TARGET_LOST, s)


def _finite_m(x: float) -> float | None:
    """A score for the records: metres to 0.1 mm, None where not finite (JSON has no infinity)."""
    return round(float(x), 4) if np.isfinite(x) else None


def drawn_starts(objects: np.ndarray, k: int, rng: np.random.Generator, resting_z: np.ndarray) -> np.ndarray:
    """k copies (k, n, 7) of the observed objects (n, 7), each object's x, y and yaw redrawn
    about what was observed with the observation noise (RESCORE_POS_NOISE, RESCORE_YAW_NOISE).
    An object seen more than 1 cm off its resting height `resting_z` (n,) (fallen, lifted or
    off the table: how the "real" world's observation tells them, `executor.observe`) keeps
    its pose as seen."""
    out = np.repeat(objects[None].astype(np.float64), k, axis=0)
    n = len(objects)
    upright = np.abs(objects[:, 2] - resting_z) < 0.01
    dxy = rng.normal(0.0, RESCORE_POS_NOISE, (k, n, 2))
    dyaw = rng.normal(0.0, RESCORE_YAW_NOISE, (k, n))
    yaw = 2.0 * np.arctan2(objects[:, 6], objects[:, 3])  # (an upright object is seen turned about z only)
    out[:, :, :2] += np.where(upright[None, :, None], dxy, 0.0)
    new_yaw = yaw[None] + dyaw
    out[:, :, 3] = np.where(upright[None], np.cos(new_yaw / 2), out[:, :, 3])
    out[:, :, 4:6] = np.where(upright[None, :, None], 0.0, out[:, :, 4:6])
    out[:, :, 6] = np.where(upright[None], np.sin(new_yaw / 2), out[:, :, 6])
    return out


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
    return np.unique(np.concatenate(found)) if found else np.zeros(0, np.int32)


@dataclass
class Simulate:
    """A planner's request: roll these actions out from this observed state (or from each of
    several states of the objects: `objects` (S, n, 7), the answer then start-major, S x
    len(actions) outcomes)."""

    robot_q: np.ndarray  # (nj,)
    objects: np.ndarray  # (n, 7) or (S, n, 7)
    actions: list[Action]

    def parts(self) -> list[tuple[np.ndarray, np.ndarray, list[Action]]]:
        """The request as `Simulator.simulate_many`'s requests, one per start state."""
        starts = self.objects if self.objects.ndim == 3 else self.objects[None]
        return [(self.robot_q, o, self.actions) for o in starts]

    @property
    def rollouts(self) -> int:
        return len(self.actions) * (len(self.objects) if self.objects.ndim == 3 else 1)


@dataclass
class Simulated:
    """The answer: final object poses (len(actions), n, 7), the seconds charged for them and,
    apart, the seconds of compilation they took (`lmjx.compiletime`; not in `seconds`)."""

    objects: np.ndarray
    seconds: float
    compile_s: float = 0.0


@dataclass
class Execute:
    """A planner's request: execute this action in the world and observe."""

    action: Action


Request = Simulate | Execute


def simulate_request(sim: Simulator, req: Simulate) -> Simulated:
    c0, t0 = compile_seconds(sim), time.perf_counter()
    final = np.concatenate(sim.simulate_many(req.parts()))
    wall, compiled = time.perf_counter() - t0, compile_seconds(sim) - c0
    return Simulated(final, max(0.0, wall - compiled), compiled)


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
            answer = executor.execute(req.action)


class Planner:
    """Algorithm 3 for one failure's map and one scenario.

    The planner is written as generators that *ask* for simulations and executions
    (`Simulate`, `Execute`) and are answered by whoever drives them: `run` answers one
    trial's requests as they come; `lmjx.lockstep` answers many trials' requests together,
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
        self.reach = reach
        self.bundle = bundle
        self.sc = sc
        self.sim = simulator
        self.config = config
        batched = bool(getattr(simulator, "prefers_batches", False))
        self.batched = batched
        self.transits = transits or TransitPlanner(robot, failure, batched=batched)
        self.transits.late_start = config.late_start  # (trials sharing a TransitPlanner share a config)
        self.field = _score_field(robot, failure, reach, bundle, sc, config)
        # edges that were executed here and did not move the target toward the goal: target
        # position at the time, per edge (not offered again while the target stays there)
        self.futile: dict[int, np.ndarray] = {}
        self.came_from: np.ndarray | None = None  # the last executed edge's states (transits retreat along it)
        self.trail: np.ndarray | None = None  # every joint target the arm followed in this trial (the way back)
        # rescoring's draws (`PlannerConfig.rescore_top`): a stream of their own, seeded by the
        # trial, so that the trial's other random choices are those it makes without them
        self.draws = np.random.default_rng(0)

    def choose(self, obs: Observation, rng: np.random.Generator) -> tuple[Action | None, StepRecord]:
        """One decision, simulating on this planner's simulator, timed as a trial times it
        (`_timed_decision`: its planning time leaves out what was compiled meanwhile,
        `StepRecord.compile_s`)."""
        return drive(self._timed_decision(obs, rng), self.sim)

    def decide(self, obs: Observation, rng: np.random.Generator) -> Generator[Simulate, Simulated, tuple]:
        """One decision: yields the simulations it needs; returns (action or None, record)."""
        cfg = self.config
        target = obs.objects[0, :2]
        self.transits.set_scene(self.sc, obs.objects)
        edges = edges_over_target(self.bundle, self.reach, target, float(self.sc.target.half[0]), cfg.target_margin)
        if cfg.futile_filter and self.futile:
            keep = [e for e in edges if not self._futile_here(int(e), target)]
            edges = np.asarray(keep, edges.dtype)
        order = rng.permutation(edges)
        now = float(self.field(target))
        rec = StepRecord(-1, len(edges), 0, None, float(goal_distance(self.sc, target)), 0.0, 0.0)
        if cfg.asm == "random":
            acts = self.transits.actions(self.bundle, order, obs.robot_q, 1, self.came_from, self.trail)
            if acts:
                rec.edge = acts[0].edge
            else:
                rec.no_action = dict(self.transits.last_tally)
            return (acts[0] if acts else None), rec
        if cfg.asm == "greedy":
            want = cfg.greedy_candidates
            if cfg.greedy_fraction is not None:
                want = max(1, math.ceil(cfg.greedy_fraction * len(edges)))
            acts = self.transits.actions(self.bundle, order, obs.robot_q, want, self.came_from, self.trail)
            if not acts:
                rec.no_action = dict(self.transits.last_tally)
                return None, rec
            done = yield Simulate(obs.robot_q, obs.objects, acts)
            s = score(self.sc, self.robot, done.objects, self.field)
            chosen_by = s  # what Greedy's choice (`best_of`) minimises
            rescoring = cfg.rescore_top > 0 and len(acts) > 1
            if rescoring:
                top = np.argsort(s, kind="stable")[: cfg.rescore_top]
                resting = np.array([b.zc for b in self.sc.movable])
                starts = drawn_starts(obs.objects, cfg.rescore_draws - 1, self.draws, resting)
                more = yield Simulate(obs.robot_q, starts, [acts[int(i)] for i in top])
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
                best, rec.stuck = self._most_options(done.objects, s)
                self.transits.set_scene(self.sc, obs.objects)  # the observed scene again
                if rec.rescored is not None and best != rescored_pick:
                    rec.rescored["overridden"] = True  # the rule when stuck took another candidate
            rec.simulated = len(acts)
            rec.predicted_distance = float(s[best])
            rec.edge = acts[best].edge
            return acts[best], rec
        # lazy: in random order, the first that brings the target closer wins
        best_a, best_s = None, np.inf
        tries = cfg.lazy_tries if cfg.lazy_cap else len(order)
        improved = False
        if self.batched:  # its tries at once, then the first improvement in their order
            acts = self.transits.actions(self.bundle, order, obs.robot_q, tries, self.came_from, self.trail)
            rec.simulated = len(acts)
            if acts:
                done = yield Simulate(obs.robot_q, obs.objects, acts)
                for a, sc in zip(acts, score(self.sc, self.robot, done.objects, self.field), strict=True):
                    if float(sc) < best_s:
                        best_a, best_s = a, float(sc)
                    if sc <= now - cfg.min_progress:
                        improved = True
                        break
            else:
                rec.no_action = dict(self.transits.last_tally)
        else:  # one at a time, stopping at the first improvement
            tally = dict.fromkeys(NO_ACTION_KEYS, 0)
            for e in order:
                if rec.simulated == tries:
                    break
                self.transits.set_scene(self.sc, obs.objects)  # again: trials run together share `transits`
                acts = self.transits.actions(self.bundle, np.array([e]), obs.robot_q, 1, self.came_from, self.trail)
                for k, v in self.transits.last_tally.items():
                    tally[k] += v
                if not acts:
                    continue
                rec.simulated += 1
                done = yield Simulate(obs.robot_q, obs.objects, acts)
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
            rec.edge = best_a.edge
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

    def _futile_here(self, edge: int, target: np.ndarray) -> bool:
        at = self.futile.get(edge)
        return at is not None and float(np.hypot(*(target - at))) < self.config.futile_radius

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
        reason = "budget"
        for _ in range(cfg.max_actions or self.sc.budget):
            if in_goal(self.sc, obs.objects[0, :2], cfg.goal_margin):
                reason = "goal"
                break
            if planning > cfg.max_planning_s:
                reason = "planning time"
                break
            action, rec = yield from self._timed_decision(obs, rng)
            planning += rec.planning_s
            if action is None:
                reason = "no feasible transit"
                if rec.candidates == 0:
                    reason = "no edge over the target"
                elif rec.simulated > 0:
                    reason = "no edge moves the target"
                steps.append(rec)
                break
            t_before = obs.time
            before = obs.objects[0, :2].copy()
            obs = yield Execute(action)
            self.came_from, self.trail = after_executing(action, self.trail, self.bundle.q_start.dtype)
            closer = float(self.field(obs.objects[0, :2])) <= float(self.field(before)) - cfg.min_progress
            if cfg.futile_filter and not closer:
                self.futile[action.edge] = before
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
            execution_s=obs.time,
            final_distance=float(goal_distance(self.sc, truth[0, :2])),
            steps=steps,
            reason="goal" if success else reason,
            stopped=reason,
        )

    def _timed_decision(self, obs: Observation, rng: np.random.Generator):
        """`decide`, with its planning time: own computation plus the simulations' charged
        seconds, each less the compilation it included (JAX's, counted apart in `compile_s`;
        the simulations' answers leave theirs out already)."""
        steps = self.decide(obs, rng)
        own, charged, compiled = 0.0, 0.0, 0.0
        answer = None
        while True:
            c0, t0 = jax_compile_seconds(), time.perf_counter()
            try:
                req = steps.send(answer)
            except StopIteration as done:
                c = jax_compile_seconds() - c0
                own += time.perf_counter() - t0 - c
                action, rec = done.value
                rec.compile_s = compiled + c
                rec.planning_s = max(0.0, own + charged)
                rec.simulation_s = charged
                return action, rec
            c = jax_compile_seconds() - c0
            own += time.perf_counter() - t0 - c
            compiled += c
            answer = yield req
            charged += answer.seconds
            compiled += answer.compile_s
