"""The planner's simulator: candidate actions rolled out from one observed scene state, in a
batch, returning where every object ends.

`CpuSimulator` uses C MuJoCo's multithreaded `mujoco.rollout` over all host cores (the CPU
path).  `lmjx.simulate_mjx.MjxSimulator` (the GPU path) implements the same interface with
MJX.  Both see only the planner's physics (`scene.Physics()` defaults), never the "real"
world's.
"""

from __future__ import annotations

import os
from typing import Protocol

import mujoco
import numpy as np
from mujoco import rollout

from .actions import Action, controls
from .scene import Scene, set_state


class Simulator(Protocol):
    def simulate(self, robot_q: np.ndarray, obj_qpos: np.ndarray, actions: list[Action]) -> np.ndarray:
        """Final object qpos (len(actions), n_objects, 7) after each action and the settle time."""
        ...


class CpuSimulator:
    """Batched rollouts with C MuJoCo on `threads` host threads (default: all cores)."""

    def __init__(self, scene: Scene, settle: float = 0.5, threads: int | None = None, segment: int = 200) -> None:
        self.scene = scene
        self.settle = settle
        self.threads = threads or os.cpu_count() or 1
        self.datas = [mujoco.MjData(scene.model) for _ in range(self.threads)]
        self.segment = segment
        self.spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        self.nstate = mujoco.mj_stateSize(scene.model, self.spec)
        self.steps_run = 0

    def initial_state(self, robot_q: np.ndarray, obj_qpos: np.ndarray) -> np.ndarray:
        d = self.datas[0]
        set_state(self.scene, d, robot_q, obj_qpos)
        state = np.empty(self.nstate)
        mujoco.mj_getState(self.scene.model, d, state, self.spec)
        return state

    def simulate(self, robot_q: np.ndarray, obj_qpos: np.ndarray, actions: list[Action]) -> np.ndarray:
        if not actions:
            return np.zeros((0, self.scene.n_objects, 7))
        m = self.scene.model
        ctrl = [controls(a, m.opt.timestep, self.settle) for a in actions]
        n = max(len(c) for c in ctrl)
        batch = np.zeros((len(actions), n, m.nu))
        for i, c in enumerate(ctrl):  # pad by holding the last control
            batch[i, : len(c)] = c
            batch[i, len(c) :] = c[-1]
        state = np.repeat(self.initial_state(robot_q, obj_qpos)[None], len(actions), axis=0)
        for start in range(0, n, self.segment):
            seg = batch[:, start : start + self.segment]
            out, _ = rollout.rollout(m, self.datas, state, seg)
            state = out[:, -1]
            self.steps_run += seg.shape[0] * seg.shape[1]
        return self._objects(state)

    def _objects(self, states: np.ndarray) -> np.ndarray:
        # FULLPHYSICS state: time, qpos, qvel, act, ...
        qpos = states[:, 1 : 1 + self.scene.model.nq]
        return np.stack([qpos[:, a : a + 7] for a in self.scene.obj_qpos], axis=1)
