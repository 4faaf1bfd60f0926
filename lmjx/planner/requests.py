"""What a planner asks of whoever drives it (`Simulate`, `Execute`) and the answers
(`Simulated`, `Executed`): one trial answered request by request (`edge_planner.drive`), or many
trials' requests answered together (`lmjx.evaluation.lockstep`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lmjx.types import Action, Observation


@dataclass
class Simulate:
    """A planner's request: roll these actions out from this observed state (or from each of
    several states of the objects: `objects` (S, n, 7), the answer then start-major, S x
    len(actions) outcomes)."""

    robot_q: np.ndarray  # (nj,)
    objects: np.ndarray  # (n, 7) or (S, n, 7)
    actions: list[Action]
    phase: str = "simulate"  # the decision's phase it serves (`lmjx.planner.phases`): simulate or rescore

    def parts(self) -> list[tuple[np.ndarray, np.ndarray, list[Action]]]:
        """The request as `Simulator.simulate_many`'s requests, one per start state."""
        starts = self.objects if self.objects.ndim == 3 else self.objects[None]
        return [(self.robot_q, o, self.actions) for o in starts]

    @property
    def rollouts(self) -> int:
        return len(self.actions) * (len(self.objects) if self.objects.ndim == 3 else 1)

    @property
    def control_steps(self) -> int:
        """The control steps the request simulates (what the planning limit counts,
        `PlannerConfig.max_sim_steps`): each action's control points, once per start."""
        return sum(len(a.q) for a in self.actions) * (len(self.objects) if self.objects.ndim == 3 else 1)


@dataclass
class Simulated:
    """The answer: final object poses (len(actions), n, 7); the wall seconds the request
    waited for them, less the compilation they took (`compile_s`, apart:
    `lmjx.runtime.compiletime`); and of `seconds`, the part spent on other requests' rollouts
    sharing the batch (`shared_s`: in proportion to the rollouts)."""

    objects: np.ndarray
    seconds: float
    compile_s: float = 0.0
    shared_s: float = 0.0


@dataclass
class Executed:
    """The answer to `Execute`: what the world's sensors report after the action, and the
    wall seconds the execution took."""

    observation: Observation
    seconds: float


@dataclass
class Execute:
    """A planner's request: execute this action in the world and observe."""

    action: Action


Request = Simulate | Execute
