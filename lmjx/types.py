"""Values the stages exchange: an action, an observation, the interfaces of the planner's
simulator and of the world actions are executed in, and the planner's configuration.

The planner produces `Action`s and reads `Observation`s; a simulator (`lmjx.sim.cpu`,
`lmjx.sim.gpu`) and an executor (the simulated "real" world `lmjx.sim.realworld`, or a real
robot's backend) consume actions.  Defining them here lets the simulators and the planner
meet without importing each other.  Nothing here computes anything.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from lmjx.errors import ConfigError
from lmjx.runtime.reprs import config_repr

if TYPE_CHECKING:
    from lmjx.sim.scenarios import Layout

CONTROL_DT = 0.02  # the edges' control period [s]: an action's joint targets are this far apart
# The planning limit's default (`PlannerConfig.max_sim_steps`), in simulated control steps: what
# the most expensive default configuration may simulate, Greedy with 1,024 candidates and
# rescoring's 8 x 7 redrawn starts (1,080 rollouts a decision), over a budget of 30 decisions,
# with actions averaging up to 1,500 control points (30 s: a transit through the roadmap can be
# several times the ~160 of an action from the park pose): 30 x 1,080 x 1,500 = 48.6 million.
# A bound on runaway planning (Lazy over every edge, Greedy over a fraction of thousands), not
# a setting the default ASMs meet, on a GPU (1,024 candidates) or a CPU (32).
MAX_SIM_STEPS = 50_000_000


@dataclass
class Action:
    """A planned action: joint targets q* and velocities qd* at the control rate."""

    edge: int  # edge id in the bundle
    q: np.ndarray  # (T, nq)
    qd: np.ndarray  # (T, nq)
    transit_steps: int  # the first transit_steps rows move to the edge's start
    via_park: bool  # the transit is not the straight line (through the park pose, or the roadmap)
    route: str = "direct"  # the transit: "direct", "park" (through the park pose), "roadmap"; "escape+" any of them
    edge_states: int = -1  # the edge's states executed (fewer than its own where a fixed obstacle cuts it short)
    edge_first: int = 0  # the edge's first state executed (`late_start`: its start in a fixed obstacle's margin)
    turn: float = 0.0  # [rad] the edge turned about the base joint by this (`turn_edges`, `lmjx.planner.turned`)

    @property
    def duration(self) -> float:
        return len(self.q) * CONTROL_DT


@dataclass
class Observation:
    """What an executor reports after a reset or an action: the arm's measured joint angles,
    the objects' estimated poses (the target first) and the execution time so far.  A pose is
    a position [m] then a unit quaternion (w, x, y, z), MuJoCo's order (`lmjx.transit` and
    `lmjx.simulate` take and give (x, y, z, w) with order="xyzw")."""

    robot_q: np.ndarray  # (nq,) measured joint angles
    objects: np.ndarray  # (n, 7) estimated object poses (position, quaternion)
    time: float  # seconds of execution so far
    # what the last executed action did (a real backend reports what it can measure):
    target_moved_m: float = float("nan")  # the target's displacement on the table [m]
    transit_contacts: tuple[str, ...] = ()  # movable objects the arm came into contact with before
    # the edge began (not those it was already touching when the transit began, until it has
    # been `LEAVE_CLEAR` clear of them)
    transit_hit_fixed: bool = False  # the arm came into contact with a fixed obstacle before the edge began
    transit_left: tuple[str, ...] = ()  # objects and obstacles the arm was touching as the transit began


class Executor(Protocol):
    """Where actions are executed: the robot and the objects, real or simulated.  A real
    robot's backend implements these three methods; `lmjx.sim.realworld.SimulatedRealWorld`
    is the reference implementation (a perturbed MuJoCo world observed with noise), and the
    planner talks to nothing else (docs/API.md, "Executor")."""

    def reset(self, layout: Layout, robot_q: np.ndarray) -> Observation:
        """Set up a trial: the objects at `layout.poses` ((n, 3) x, y, yaw: a real backend
        asks for them to be placed so, or reports where they are), the arm moved to `robot_q`
        (nq,); return the first observation."""
        ...

    def execute(self, action: Action) -> Observation:
        """Run `action` (joint targets `action.q` and velocities `action.qd`, (T, nq), one
        row every CONTROL_DT: the transit's first `transit_steps` rows, then the edge's),
        wait for the objects to come to rest, and observe."""
        ...

    def truth(self) -> np.ndarray:
        """(n, 7) true object poses (for scoring trials; a real backend returns its best estimate)."""
        ...


SimRequest = tuple[np.ndarray, np.ndarray, list[Action]]  # robot_q (nj,), objects (n, 7), actions


class Simulator(Protocol):
    name: str  # "cpu", "cpu-near", "gpu"
    prefers_batches: bool  # True where a batch of many costs about what one candidate does
    steps_run: int

    @property
    def description(self) -> str: ...

    def simulate(self, robot_q: np.ndarray, obj_qpos: np.ndarray, actions: list[Action]) -> np.ndarray:
        """Final object qpos (len(actions), n_objects, 7) after each action and the settle time."""
        ...

    def simulate_many(self, requests: list[SimRequest]) -> list[np.ndarray]:
        """`simulate` for several (robot_q, objects, actions) requests."""
        ...


ASMS = ("random", "lazy", "greedy")
WHEN_STUCK = ("best", "options")
SERVOS = ("playback", "robot")  # the planner simulator's servo models (`PlannerConfig.servo`)

# rescoring's draws of the observed poses: the "real" world's observation noise
# (`executor.SimulatedRealWorld`: x, y each N(0, 2 mm), yaw N(0, 1.5 deg))
RESCORE_POS_NOISE = 0.002  # [m]
RESCORE_YAW_NOISE = math.radians(1.5)  # [rad]
OPTIONS_NEAR = 0.8  # when_stuck="options": candidates with at least this share of the most options qualify


def _lever(default: object, meaning: str, **bounds: object) -> Any:
    """A PlannerConfig field: its default, what it means (`lmjx plan --help-levers`,
    docs/PLANNER.md) and the values it takes (`choices`, `least`, `above` and `most`: checked
    where users set it, `lmjx.planner.levers`)."""
    return field(default=default, metadata={"meaning": meaning, **bounds})


@dataclass(frozen=True)
class PlannerConfig:
    """The planner's settings (Algorithm 3): the action selection mechanism and every lever of
    it, with its default and meaning.  The commands take the levers as keys of this class
    (`--set KEY=VALUE`, `--planner-config FILE`: `lmjx.planner.levers`); `settings()` is
    what the results record of them."""

    asm: str = _lever("greedy", "the action selection mechanism (--asm, --asms)", choices=ASMS)
    max_actions: int | None = _lever(None, "the action budget per task (--max-actions); none: the task set's", least=1)
    max_sim_steps: int = _lever(
        MAX_SIM_STEPS,
        "the planning limit: a trial stops, a failure unless its target is in the goal, before its next decision "
        "once its planner has simulated this many control steps (20 ms of an action's motion each, counted per "
        "candidate rollout and start: the same count on every host and simulator); planning time (wall clock) is "
        "measured but stops nothing",
        least=1,
    )
    greedy_candidates: int = _lever(
        32,
        "greedy: candidate actions simulated per decision (--candidates; the commands' default: 1024 with the GPU "
        "simulator, 32 on the CPU)",
        least=1,
    )
    lazy_tries: int = _lever(32, "lazy: simulations per decision at most (with lazy_cap)", least=1)
    min_progress: float = _lever(
        0.005, "[m] an action 'moves the target toward the goal' when its score drops by at least this", least=0.0
    )
    target_margin: float = _lever(
        0.01, "[m] the edges offered pass over the reach cells within the target's half size plus this", least=0.0
    )
    goal_margin: float = _lever(
        0.01, "[m] the planner stops once the observed target is this far inside the goal region", least=0.0
    )
    futile_radius: float = _lever(
        0.01,
        "[m] an executed edge that did not bring the target closer is not offered again while the target stays "
        "within this distance of where it was (futile_filter)",
        least=0.0,
    )
    # lmjx's refinements of the paper's ASMs, each of which can be turned off (`paper()`):
    futile_filter: bool = _lever(True, "edges that failed here are not offered again (futile_radius)")
    path_score: bool = _lever(
        True, "'closest' is the path length around the fixed obstacles; false: the straight distance"
    )
    lazy_fallback: bool = _lever(
        True, "lazy takes its best simulated edge when none brings the target closer; false: no action"
    )
    lazy_cap: bool = _lever(True, "lazy stops after lazy_tries simulations; false: it may try every edge")
    greedy_fraction: float | None = _lever(
        None,
        "greedy simulates this fraction (0 to 1) of the edges over the target (at least one) instead of "
        "greedy_candidates; none: greedy_candidates",
        above=0.0,
        most=1.0,
    )
    when_stuck: str = _lever(
        "best",
        "greedy, when no candidate is predicted to bring the target min_progress closer: best takes the best "
        "predicted all the same (the paper's Greedy); options takes, of the candidates that keep every object on "
        "the table, the one whose predicted state leaves the most edges to offer (starts clear, acting on the "
        "target), the best predicted of those within 80% of the most (OPTIONS_NEAR)",
        choices=WHEN_STUCK,
    )
    late_start: bool = _lever(
        False,
        "where the edges with clear starts give fewer candidates than wanted, an edge whose start lies within a "
        "fixed obstacle's margin (2 cm) is offered from its first state clear of the scene, where that part "
        "still acts on the target; false: such an edge is not offered",
    )
    turn_edges: bool = _lever(
        True,
        "after the map's own edges over the target, offer copies of the map's edges turned about the arm's base "
        "joint (free, its axis vertical: the same motion, torques and velocities, about the base) so that they "
        "pass over the target (whole degrees, at most 4 turns an edge); false: the map's edges alone",
    )
    # push_weight 1: on the hard tunnel's calibration seeds 23 of 30 trials with it against 14 without
    push_weight: float = _lever(
        1.0,
        "> 0: 'closest' is the cost of the cheapest way to the goal, each metre weighted by how rarely the map's "
        "edges push toward the goal there: 1 + push_weight ln(median / pushes), at least 1 (the counts take "
        "minutes per map and scenario on a CPU, then are kept in lmjx's cache folder); 0: the path length alone "
        "(path_score); needs path_score",
        least=0.0,
    )
    # rescore_top 8 (x 8 draws): the hard tunnel's calibration trials 26 of 30 with it against 23 without
    rescore_top: int = _lever(
        8,
        "> 0: greedy simulates its this many best candidates again from rescore_draws - 1 more starts, every "
        "object's observed pose redrawn with the camera's noise (2 mm, 1.5 deg), and takes the one with the "
        "lowest mean score over all its starts (a push whose outcome hangs on millimetres no longer wins on one "
        "lucky rollout); 0: off",
        least=0,
    )
    rescore_draws: int = _lever(8, "starts per rescored candidate, the observed one included", least=2)
    # servo "robot": of the "real" world's differences the servos move a push's result as much as any and
    # are the one the planner can know; the hard tunnel's calibration trials 28 of 30 against 26 with playback
    servo: str = _lever(
        "robot",
        "how the planner's simulator tracks the arm's joint targets: robot (the robot's own joint servo gains "
        "and torque limits, as its controller tracks them: a simulated push lags and overshoots as the arm's "
        "does) or playback (stiff servos with unlimited torque: the trajectory played back nearly exactly)",
        choices=SERVOS,
    )

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
                "straight distance: leave out --push-weight (push_weight) or the paper's settings (asm_settings=paper)"
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
        rescoring: the paper's Greedy takes its best simulated candidate), the map's edges alone
        (none turned)."""
        return replace(self, futile_filter=False, path_score=False, lazy_fallback=False, lazy_cap=False,
                       greedy_fraction=0.25, push_weight=0.0, rescore_top=0, turn_edges=False)  # fmt: skip

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
            "turn_edges": self.turn_edges,
            "push_weight": self.push_weight,
            # (only Greedy's, and only when on: the records of runs before it existed read the same)
            **(
                {"rescore": f"best {self.rescore_top}, {self.rescore_draws} starts"}
                if self.rescore_top and (asm or self.asm) == "greedy"
                else {}
            ),
            # (only where not the playback, and only for the ASMs that simulate: as above)
            **({"servo": self.servo} if self.servo != "playback" and (asm or self.asm) != "random" else {}),
            # the other levers, only where they differ from their defaults
            **{k: getattr(self, k) for k in UNLISTED if getattr(self, k) != _DEFAULTS[k]},
        }


# the fields `settings()` lists only where they differ from their defaults (the others it always lists)
UNLISTED = ("max_sim_steps", "min_progress", "target_margin", "goal_margin", "futile_radius")
_DEFAULTS = {f.name: f.default for f in fields(PlannerConfig)}
