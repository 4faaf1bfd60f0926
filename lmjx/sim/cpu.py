"""The planner's simulator: candidate actions rolled out from one observed scene state, in a
batch, returning where every object ends.

`CpuSimulator` uses C MuJoCo's multithreaded `mujoco.rollout` over all host cores (the CPU
path, and the reference every other simulator is tested against).
`lmjx.sim.gpu.GpuSimulator` (the GPU path) implements the same interface with MuJoCo
Warp.  Both see only the planner's physics (`scene.Physics()` defaults), never the "real"
world's.
"""

from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np
from mujoco import rollout

from lmjx.model.robot import Robot
from lmjx.runtime.cores import usable_cores
from lmjx.sim.controls import controls
from lmjx.sim.scenarios import Scenario
from lmjx.sim.scene import Scene, build_scene, set_state
from lmjx.types import Action, SimRequest


def nearest_objects(obj_qpos: np.ndarray, k: int) -> list[int]:
    """The target (0) and the k - 1 objects nearest to it (observed centres)."""
    dist = np.hypot(*(obj_qpos[:, :2] - obj_qpos[0, :2]).T)
    return [0, *[int(i) for i in np.argsort(dist, kind="stable") if i != 0][: k - 1]]


def subscenario(sc: Scenario, chosen: list[int]) -> Scenario:
    """The scenario with only the movable objects `chosen` (the first becomes the target)."""
    return replace(sc, target=sc.movable[chosen[0]], obstacles=tuple(sc.movable[i] for i in chosen[1:]))


def padded_controls(actions: list[Action], physics_dt: float, settle: float) -> tuple[np.ndarray, np.ndarray]:
    """Servo controls (len(actions), steps, nu) of every action, each held at its last control
    until the longest one ends, and each action's own number of steps (len(actions),)."""
    ctrl = [controls(a, physics_dt, settle) for a in actions]
    ends = np.array([len(c) for c in ctrl])
    out = np.zeros((len(actions), int(ends.max()), ctrl[0].shape[1]))
    for i, c in enumerate(ctrl):
        out[i, : len(c)] = c
        out[i, len(c) :] = c[-1]
    return out, ends


class CpuSimulator:
    """Batched rollouts with C MuJoCo on `threads` host threads (default: all cores).

    With `k_objects`, only the target and its `k_objects - 1` nearest objects (as observed)
    are simulated; the others stay where they were seen (the approximation the MJX path
    makes; `lmjx bench` measures what it costs in agreement).  Scenes are built per chosen
    set of objects and kept.
    """

    def __init__(
        self,
        scene: Scene,
        settle: float = 0.5,
        threads: int | None = None,
        segment: int = 200,
        k_objects: int | None = None,
        robot: Robot | None = None,
    ) -> None:
        self.scene = scene
        self.settle = settle
        self.threads = threads or usable_cores()
        self.segment = segment
        self.spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        self.k = None if k_objects is None else min(k_objects, scene.n_objects)
        if self.k is not None and robot is None:
            raise ValueError("k_objects needs the robot (to build the reduced scenes)")
        self.robot = robot
        self.full = scene
        # per set of simulated objects (None: all): the scene and the threads' data
        self._built: dict[tuple[int, ...] | None, tuple[Scene, list[mujoco.MjData]]] = {}
        self._select(None)
        self.steps_run = 0
        self.name = "cpu" if self.k is None else "cpu-near"

    prefers_batches = False

    @property
    def description(self) -> str:
        what = "whole scene" if self.k is None else f"the target and its {self.k - 1} nearest objects"
        return f"C MuJoCo mujoco.rollout on {self.threads} threads, {what}"

    def simulate_many(self, requests: list[SimRequest]) -> list[np.ndarray]:
        return [self.simulate(*r) for r in requests]

    def _select(self, chosen: tuple[int, ...] | None) -> None:
        if chosen not in self._built:
            assert chosen is None or self.robot is not None
            scene = self.full if chosen is None else build_scene(
                self.robot, subscenario(self.full.scenario, list(chosen)), self.full.physics
            )  # fmt: skip
            self._built[chosen] = (scene, [mujoco.MjData(scene.model) for _ in range(self.threads)])
        self.scene, self.datas = self._built[chosen]
        self.nstate = mujoco.mj_stateSize(self.scene.model, self.spec)

    def initial_state(self, robot_q: np.ndarray, obj_qpos: np.ndarray) -> np.ndarray:
        d = self.datas[0]
        set_state(self.scene, d, robot_q, obj_qpos)
        state = np.empty(self.nstate)
        mujoco.mj_getState(self.scene.model, d, state, self.spec)
        return state

    def simulate(self, robot_q: np.ndarray, obj_qpos: np.ndarray, actions: list[Action]) -> np.ndarray:
        if not actions:
            return np.zeros((0, len(obj_qpos), 7))
        if self.k is None:
            return self._simulate(robot_q, obj_qpos, actions)
        chosen = nearest_objects(obj_qpos, self.k)
        self._select(tuple(chosen))
        part = self._simulate(robot_q, obj_qpos[chosen], actions)
        final = np.repeat(obj_qpos[None], len(actions), axis=0).astype(np.float64)
        final[:, chosen] = part
        return final

    def _simulate(self, robot_q: np.ndarray, obj_qpos: np.ndarray, actions: list[Action]) -> np.ndarray:
        """Each action simulated for exactly its own steps (its state is taken where it ends,
        whatever else shares the batch)."""
        m = self.scene.model
        batch, ends = padded_controls(actions, m.opt.timestep, self.settle)
        n = batch.shape[1]
        state = np.repeat(self.initial_state(robot_q, obj_qpos)[None], len(actions), axis=0)
        final = np.empty_like(state)
        for start in range(0, n, self.segment):
            seg = batch[:, start : start + self.segment]
            out, _ = rollout.rollout(m, self.datas, state, seg)
            state = out[:, -1]
            here = np.nonzero((ends > start) & (ends <= start + seg.shape[1]))[0]
            final[here] = out[here, ends[here] - start - 1]
            self.steps_run += seg.shape[0] * seg.shape[1]
        return self._objects(final)

    def _objects(self, states: np.ndarray) -> np.ndarray:
        # FULLPHYSICS state: time, qpos, qvel, act, ...
        qpos = states[:, 1 : 1 + self.scene.model.nq]
        return np.stack([qpos[:, a : a + 7] for a in self.scene.obj_qpos], axis=1)
