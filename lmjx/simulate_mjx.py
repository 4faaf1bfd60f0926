"""The planner's simulator on an accelerator: candidate actions rolled out with MuJoCo MJX.

Same interface as `simulate.CpuSimulator`.  What makes it fast enough (measured in
benchmarks/RESULTS.md), each a documented approximation of the CPU simulator's scene:
  * only the objects near the target are simulated: the target and its `k_objects - 1`
    nearest neighbours; the others stay where they were observed and the score treats them
    as unmoved;
  * the table is a plane (box-plane contacts are cheap in MJX, box-box ones are not);
  * MJX's broad phase keeps the `max_contact_points` closest geom pairs per type and the
    deepest contacts, and the constraint solver runs `solver_iterations` iterations;
  * the batch and the segment length are fixed, so one program serves every call: actions
    are rolled out `segment` steps at a time, in a batch padded to `batch`.
Everything else (time step, servos, friction, masses, contact groups) is the CPU scene's.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from .actions import Action
from .robot import Robot
from .scenarios import Scenario
from .scene import Physics, build_scene, set_state
from .simulate import nearest_objects, padded_controls, subscenario

MJX_PHYSICS = Physics(table_as_plane=True, solver_iterations=6, max_contact_points=12)


class MjxSimulator:
    def __init__(
        self,
        robot: Robot,
        scenario: Scenario,
        settle: float = 0.5,
        k_objects: int = 4,
        batch: int = 256,
        segment: int = 100,
        physics: Physics = MJX_PHYSICS,
    ) -> None:
        self.robot = robot
        self.scenario = scenario
        self.settle = settle
        self.k = min(k_objects, len(scenario.movable))
        self.batch = batch
        self.segment = segment
        self.physics = physics
        self._step = jax.jit(self._segment_fn)
        self.steps_run = 0

    @staticmethod
    def _segment_fn(m: mjx.Model, d: mjx.Data, ctrl: jnp.ndarray) -> mjx.Data:
        """Advance a batch of states by ctrl.shape[1] steps; ctrl (B, S, nu)."""

        def one(d1: mjx.Data, c: jnp.ndarray) -> mjx.Data:
            def body(dd: mjx.Data, u: jnp.ndarray) -> tuple[mjx.Data, None]:
                return mjx.step(m, dd.replace(ctrl=u)), None

            out, _ = jax.lax.scan(body, d1, c)
            return out

        return jax.vmap(one)(d, ctrl)

    def simulate(self, robot_q: np.ndarray, obj_qpos: np.ndarray, actions: list[Action]) -> np.ndarray:
        n = len(actions)
        if n == 0:
            return np.zeros((0, len(obj_qpos), 7))
        chosen = nearest_objects(obj_qpos, self.k)
        scene = build_scene(self.robot, subscenario(self.scenario, chosen), self.physics)
        m = scene.model
        host = mujoco.MjData(m)
        set_state(scene, host, robot_q, obj_qpos[chosen])
        mx = mjx.put_model(m)
        d0 = mjx.make_data(mx).replace(
            qpos=jnp.asarray(host.qpos, jnp.float32), ctrl=jnp.asarray(host.ctrl, jnp.float32)
        )
        ctrl = padded_controls(actions, m.opt.timestep, self.settle)
        steps = -(-ctrl.shape[1] // self.segment) * self.segment  # whole segments, last controls held
        ctrl = np.concatenate([ctrl, np.repeat(ctrl[:, -1:], steps - ctrl.shape[1], axis=1)], axis=1)
        out = np.empty((n, len(chosen), 7))
        for start in range(0, n, self.batch):
            part = ctrl[start : start + self.batch]
            u = np.repeat(part[:1], self.batch, axis=0).astype(np.float32)  # the batch padded with the first
            u[: len(part)] = part
            d = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (self.batch, *x.shape)), d0)
            for s in range(0, steps, self.segment):
                d = self._step(mx, d, jnp.asarray(u[:, s : s + self.segment]))
                self.steps_run += len(part) * self.segment
            qpos = np.asarray(d.qpos)[: len(part)]
            out[start : start + len(part)] = np.stack([qpos[:, a : a + 7] for a in scene.obj_qpos], axis=1)
        final = np.repeat(obj_qpos[None], n, axis=0).astype(np.float64)
        final[:, chosen] = out
        return final
