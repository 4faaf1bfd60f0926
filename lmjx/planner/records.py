"""What a trial leaves behind: a record of each decision (`StepRecord`) and of the whole
trial (`TrialResult`), as the evaluation writes them to results.json.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


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
    turn_deg: int = 0  # the edge executed turned about the base joint by this [deg] (`Action.turn`: turn_edges)
    compile_s: float = 0.0  # seconds of compilation during the decision, not in planning_s (`lmjx.runtime.compiletime`)
    simulation_s: float = 0.0  # of planning_s, the seconds it waited for its simulations (not in the records)
    # the wall time from the observation to the chosen action, compiling excluded (its own
    # computation and the simulations it waited for): planning_s is the same figure
    latency_s: float = 0.0
    # where the decision's time went (`lmjx.planner.phases.PHASES`: offer, transit, simulate,
    # rescore, execute, compile), wall seconds
    phase_s: dict = field(default_factory=dict)
    shared_s: float = 0.0  # of its simulations' seconds, those spent on other trials' candidates sharing its batches
    sim_steps: int = 0  # control steps its simulations rolled out (`Simulate.control_steps`: what the limit counts)
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
        # the candidates are the map's edges over the target and, with turn_edges, copies of the map's
        # edges turned about the base joint to pass over it: they may outnumber the map's edges
        moved = "" if np.isnan(self.target_moved_m) else f", target moved {self.target_moved_m * 100:.1f} cm"
        edge = "no action" if self.edge < 0 else f"edge {self.edge}"
        if self.edge >= 0 and self.turn_deg:
            edge += f" (turned {self.turn_deg} deg)"
        n = self.candidates
        among = f"{'of' if self.edge >= 0 else 'among'} {n:,} candidate{'' if n == 1 else 's'}"
        return (
            f"StepRecord({edge} {among} (the map's edges over the target and any turned copies of its edges), "
            f"{self.simulated:,} simulated; {self.distance_after * 100:.1f} cm from the goal's centre after{moved}; "
            f"transit {self.transit_route or '-'})"
        )

    def summary(self) -> dict:
        return {
            "edge": self.edge,
            "candidates": self.candidates,
            "simulated": self.simulated,
            "distance_after_m": round(self.distance_after, 4),
            "planning_s": round(self.planning_s, 3),
            "latency_s": round(self.latency_s, 4),
            "phase_s": dict(self.phase_s),
            **({"shared_s": round(self.shared_s, 4)} if self.shared_s >= 0.0005 else {}),
            "target_moved_m": None if np.isnan(self.target_moved_m) else round(self.target_moved_m, 4),
            "predicted_score_m": None if self.predicted_distance is None else round(self.predicted_distance, 4),
            "score_after_m": None if np.isnan(self.score_after) else round(self.score_after, 4),
            "transit_contacts": list(self.transit_contacts),
            "transit_hit_fixed": self.transit_hit_fixed,
            "transit_left": list(self.transit_left),
            "transit_route": self.transit_route,
            "edge_states": self.edge_states,
            **({"edge_first": self.edge_first} if self.edge_first else {}),
            **({"turn_deg": self.turn_deg} if self.turn_deg else {}),
            **({"compile_s": round(self.compile_s, 3)} if self.compile_s >= 0.0005 else {}),
            **({"sim_steps": self.sim_steps} if self.sim_steps else {}),
            **({"no_action": self.no_action} if self.no_action is not None else {}),
            **({"stuck": self.stuck} if self.stuck is not None else {}),
            **({"rescored": self.rescored} if self.rescored is not None else {}),
        }


# How a trial can end (`TrialResult.reason`, `stopped`; where each is set: `Planner.trial`; what each
# means, as `lmjx plan --help-ends` prints it: `lmjx.cli.plan.END_MEANINGS`).  "no feasible transit":
# edges over the target were tested and some lacked only a transit; "no feasible action": none lacked
# only one (their starts blocked, or the edges unusable there)
ENDS = ("goal", "budget", "planning limit", "no edge over the target", "no feasible transit",
        "no feasible action", "no edge moves the target", "target off the table")  # fmt: skip


@dataclass
class TrialResult:
    success: bool
    actions: int
    planning_s: float  # the sum of its decisions' latencies (`StepRecord.latency_s`)
    execution_s: float
    final_distance: float
    steps: list[StepRecord] = field(default_factory=list)
    reason: str = ""  # how the trial ended: "goal" whenever the target ends in the goal (success)
    compile_s: float = 0.0  # seconds its decisions spent compiling (not in planning_s; `lmjx.runtime.compiletime`)
    sim_steps: int = 0  # control steps its planner simulated (the planning limit counts them: max_sim_steps)
    stopped: str = ""  # what stopped the planner (one of ENDS): it stops once the observed target
    # is `goal_margin` inside the goal, so a target that ended in the goal but nearer its edge
    # shows here what came next (e.g. "no feasible transit")

    def __repr__(self) -> str:
        end = "success" if self.success else "failure"
        return (
            f"TrialResult({end} ({self.reason}) after {self.actions} action{'' if self.actions == 1 else 's'}; "
            f"planning {self.planning_s:.1f} s, "
            f"robot time {self.execution_s:.1f} s; target {self.final_distance * 100:.1f} cm from the goal's centre)"
        )

    def summary(self) -> dict:
        return {
            "success": self.success,
            "actions": self.actions,
            "planning_s": round(self.planning_s, 3),
            "compile_s": round(self.compile_s, 3),
            "sim_steps": self.sim_steps,
            "execution_s": round(self.execution_s, 3),
            "final_distance_m": round(self.final_distance, 4),
            "end": self.reason,
            "stopped": self.stopped or self.reason,
        }

    def action_records(self) -> list[dict]:
        """Per executed action: what it did (see `StepRecord.summary`)."""
        return [s.summary() for s in self.steps if s.edge >= 0]
