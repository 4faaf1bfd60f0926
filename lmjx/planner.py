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
            leaves the table) is taken.
"Closest" is the path length around the fixed obstacles (`GoalField`; the plain distance
where nothing is in the way).  An edge that was executed and did not bring the target closer
is not offered again while the target stays where it was (the simulator was wrong about it
once; trying it again would waste the action budget).
Execute it in the "real" world, observe, repeat until the target is in the goal region or
the budget (actions, planning time) is spent.  Actions whose transit would hit the table or
the arm itself are skipped.  Everything random comes from the trial's seed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .actions import Action, TransitPlanner
from .bundle import Bundle
from .errors import ConfigError
from .executor import Executor, Observation
from .failure import Failure
from .goalfield import GoalField
from .reach import ReachResult
from .robot import Robot
from .scenarios import Layout, Scenario, in_goal
from .simulate import Simulator

ASMS = ("random", "lazy", "greedy")
OFF_TABLE_PENALTY = 1.0  # [m] per object that leaves the table
TARGET_LOST = 10.0  # [m] when the target leaves the table


@dataclass(frozen=True)
class PlannerConfig:
    asm: str = "greedy"
    max_actions: int = 30
    max_planning_s: float = 600.0
    greedy_candidates: int = 32
    lazy_tries: int = 32
    min_progress: float = 0.005  # "moved toward the goal": the distance drops by at least this [m]
    target_margin: float = 0.01  # edges over cells within the target's half size + this [m]
    goal_margin: float = 0.01  # stop once the observed target is this far inside the goal region [m]
    futile_radius: float = 0.01  # an executed edge that made no progress is not offered again
    # while the target stays within this distance of where it was [m]

    def validate(self) -> None:
        if self.asm not in ASMS:
            raise ConfigError(f"unknown action selection mechanism '{self.asm}'; use random, lazy or greedy")
        if self.max_actions < 1 or self.greedy_candidates < 1 or self.lazy_tries < 1:
            raise ConfigError("max_actions, greedy_candidates and lazy_tries must be positive")


@dataclass
class StepRecord:
    edge: int
    candidates: int
    simulated: int
    predicted_distance: float | None
    distance_after: float
    planning_s: float
    execution_s: float


@dataclass
class TrialResult:
    success: bool
    actions: int
    planning_s: float
    execution_s: float
    final_distance: float
    steps: list[StepRecord] = field(default_factory=list)
    reason: str = ""

    def summary(self) -> dict:
        return {
            "success": self.success,
            "actions": self.actions,
            "planning_s": round(self.planning_s, 3),
            "execution_s": round(self.execution_s, 3),
            "final_distance_m": round(self.final_distance, 4),
            "end": self.reason,
        }


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


class Planner:
    """Algorithm 3 for one failure's map and one scenario."""

    def __init__(
        self,
        robot: Robot,
        failure: Failure,
        reach: ReachResult,
        bundle: Bundle,
        sc: Scenario,
        simulator: Simulator,
        config: PlannerConfig,
    ) -> None:
        config.validate()
        self.robot = robot
        self.reach = reach
        self.bundle = bundle
        self.sc = sc
        self.sim = simulator
        self.config = config
        self.transits = TransitPlanner(robot, failure)
        self.field = GoalField(sc, *table_bounds(robot))
        # edges that were executed here and did not move the target toward the goal: target
        # position at the time, per edge (not offered again while the target stays there)
        self.futile: dict[int, np.ndarray] = {}

    def _actions(self, edges: np.ndarray, q_now: np.ndarray, want: int) -> list[Action]:
        """Up to `want` feasible actions from `edges`, in the given order."""
        out = []
        for e in edges:
            a = self.transits.action(self.bundle, int(e), q_now)
            if a is not None:
                out.append(a)
                if len(out) == want:
                    break
        return out

    def choose(self, obs: Observation, rng: np.random.Generator) -> tuple[Action | None, StepRecord]:
        cfg = self.config
        target = obs.objects[0, :2]
        edges = edges_over_target(self.bundle, self.reach, target, float(self.sc.target.half[0]), cfg.target_margin)
        if self.futile:
            keep = [e for e in edges if not self._futile_here(int(e), target)]
            edges = np.asarray(keep, edges.dtype)
        order = rng.permutation(edges)
        now = float(self.field(target))
        rec = StepRecord(-1, len(edges), 0, None, float(goal_distance(self.sc, target)), 0.0, 0.0)
        if cfg.asm == "random":
            acts = self._actions(order, obs.robot_q, 1)
            if acts:
                rec.edge = acts[0].edge
            return (acts[0] if acts else None), rec
        if cfg.asm == "greedy":
            acts = self._actions(order, obs.robot_q, cfg.greedy_candidates)
            if not acts:
                return None, rec
            final = self.sim.simulate(obs.robot_q, obs.objects, acts)
            s = score(self.sc, self.robot, final, self.field)
            best = int(np.argmin(s))
            rec.simulated = len(acts)
            rec.predicted_distance = float(s[best])
            rec.edge = acts[best].edge
            return acts[best], rec
        # lazy: one by one, first improvement wins
        best_a, best_s = None, np.inf
        tried = 0
        for e in order:
            if tried == cfg.lazy_tries:
                break
            acts = self._actions([e], obs.robot_q, 1)
            if not acts:
                continue
            tried += 1
            s = float(score(self.sc, self.robot, self.sim.simulate(obs.robot_q, obs.objects, acts), self.field)[0])
            if s < best_s:
                best_a, best_s = acts[0], s
            if s <= now - cfg.min_progress:
                break
        rec.simulated = tried
        if best_a is not None:
            rec.edge = best_a.edge
            rec.predicted_distance = best_s
        return best_a, rec

    def _futile_here(self, edge: int, target: np.ndarray) -> bool:
        at = self.futile.get(edge)
        return at is not None and float(np.hypot(*(target - at))) < self.config.futile_radius

    def run(self, executor: Executor, layout: Layout, seed: int) -> TrialResult:
        """One closed-loop trial."""
        cfg = self.config
        rng = np.random.default_rng(seed)
        self.futile = {}
        obs = executor.reset(layout, self.transits.park)
        steps: list[StepRecord] = []
        planning = 0.0
        reason = "budget"
        for _ in range(cfg.max_actions):
            if in_goal(self.sc, obs.objects[0, :2], cfg.goal_margin):
                reason = "goal"
                break
            if planning > cfg.max_planning_s:
                reason = "planning time"
                break
            t0 = time.perf_counter()
            action, rec = self.choose(obs, rng)
            rec.planning_s = time.perf_counter() - t0
            planning += rec.planning_s
            if action is None:
                reason = "no edge" if rec.candidates == 0 else "no feasible transit"
                steps.append(rec)
                break
            t_before = obs.time
            before = obs.objects[0, :2].copy()
            obs = executor.execute(action)
            if float(self.field(obs.objects[0, :2])) > float(self.field(before)) - cfg.min_progress:
                self.futile[action.edge] = before
            rec.execution_s = obs.time - t_before
            rec.distance_after = float(goal_distance(self.sc, obs.objects[0, :2]))
            steps.append(rec)
        else:
            if in_goal(self.sc, obs.objects[0, :2], cfg.goal_margin):
                reason = "goal"
        truth = executor.truth()
        success = in_goal(self.sc, truth[0, :2]) and truth[0, 2] > -0.02
        return TrialResult(
            success=bool(success),
            actions=sum(1 for s in steps if s.edge >= 0),
            planning_s=planning,
            execution_s=obs.time,
            final_distance=float(goal_distance(self.sc, truth[0, :2])),
            steps=steps,
            reason=reason,
        )
