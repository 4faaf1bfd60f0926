"""The "real" world: where chosen actions are executed and the scene is observed.

There is no real robot here, so `SimulatedRealWorld` runs actions in a separate MuJoCo world
whose physics differ from the planner's simulator the way reality differs from a simulator,
drawn per trial from its seed:
  * object friction x U(0.7, 1.3) per object, table friction x U(0.8, 1.2);
  * object masses x U(0.8, 1.25) per object;
  * the robot's collision capsules U(-3, +3) mm thicker or thinner;
  * servo tracking with the robot's "real" joint gains (`RobotProfile.real_kp`, `real_kv`:
    Franka-like for the Panda) and its torque limits instead of near-exact playback;
  * object poses observed with noise: N(0, 2 mm) on x, y and N(0, 1.5 deg) on yaw; an
    object is seen upright at its resting height unless it lies 1 cm off it (or, a
    cylinder, its axis leans more than 10 deg): then at the height where it is.
The planner sees only observations.  A real robot backend implements `Executor`.
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np
from mujoco import rollout

from lmjx.model.robot import Robot
from lmjx.sim.controls import controls
from lmjx.sim.scenarios import Layout
from lmjx.sim.scene import Physics, Scene, build_scene, object_qpos, quat_yaw, read_objects, set_state
from lmjx.types import CONTROL_DT, Action, Observation

# A contact the arm is in when a transit begins (the last edge ended against the target) is
# still being left until the arm has been this far clear of that object: as a link slides off
# a box the contact solver makes and breaks the contact many times at sub-millimetre distances
# (measured: the target's contact chattered for 0.2 s with gaps of 5-25 ms, trial
# case1:1:1008 of the paper set; on calibration seeds of the hard set, contacts returning
# after 50-80 ms of absence with the arm never more than 0.32 mm away).  Once the arm has
# been this far away, touching the object again counts.
LEAVE_CLEAR = 0.001  # [m]
UPRIGHT_COS = float(np.cos(np.radians(10.0)))  # a cylinder tilted further than 10 deg is seen as it lies


class TransitContacts:
    """What a transit touches, from the contacts seen at each physics step: an object or
    obstacle the arm enters contact with, except those it was touching when the transit
    began until it has been LEAVE_CLEAR clear of them (`leaving`)."""

    def __init__(self, objects: set[str], fixed: set[str]) -> None:
        self.left = objects | fixed  # touching as the transit began
        self.leaving = set(self.left)  # ... and not yet LEAVE_CLEAR clear of
        self._prev = (set(objects), set(fixed))
        self.objects: set[str] = set()  # movable objects touched
        self.fixed: set[str] = set()  # fixed obstacles touched

    def update(self, objects: set[str], fixed: set[str], clear: set[str] | frozenset = frozenset()) -> None:
        """The contacts at one physics step; `clear`: those of `leaving` the arm is now at
        least LEAVE_CLEAR away from."""
        self.leaving -= clear
        self.objects |= objects - self._prev[0] - self.leaving
        self.fixed |= fixed - self._prev[1] - self.leaving
        self._prev = (set(objects), set(fixed))


def real_gains(robot: Robot) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The "real" world's joint servo gains kp [Nm/rad], kv [Nm s/rad]: the robot profile's
    (the Panda's: the joint impedance of libfranka's examples), else stiffness in proportion
    to each joint's torque limit (7 Nm/rad per Nm, about the Panda's base joints') with a
    twelfth of it as damping."""
    p = robot.profile
    if p.real_kp is not None and p.real_kv is not None:
        return p.real_kp, p.real_kv
    kp = tuple(float(7.0 * t) for t in robot.tau_max)
    return kp, tuple(k / 12.0 for k in kp)


def real_physics(robot: Robot, n_objects: int, rng: np.random.Generator) -> Physics:
    kp, kv = real_gains(robot)
    return Physics(
        friction_scale=tuple(rng.uniform(0.7, 1.3, n_objects)),
        mass_scale=tuple(rng.uniform(0.8, 1.25, n_objects)),
        table_friction_scale=float(rng.uniform(0.8, 1.2)),
        robot_radius_offset=float(rng.uniform(-0.003, 0.003)),
        servo_kp=kp,
        servo_kv=kv,
        servo_force=tuple(robot.tau_max),
        robot_table_contacts=True,
    )


class SimulatedRealWorld:
    """A perturbed MuJoCo world standing in for the real robot and objects: the reference
    implementation of `lmjx.types.Executor`.  Its physics are drawn from `seed` (module
    docstring) at each `reset`; `settle`: seconds the objects are left to come to rest after
    each action.  `robot`: a Robot, a shipped robot's name or an MJCF's path."""

    def __init__(self, robot: Robot | str, seed: int, settle: float = 0.5) -> None:
        from lmjx.model.robot import as_robot

        self.robot = as_robot(robot)
        self.seed = seed
        self.settle = settle
        self.scene: Scene | None = None
        self.data: mujoco.MjData | None = None
        self.rng = np.random.default_rng(seed)
        self.time = 0.0
        self.pos_noise = 0.002
        self.yaw_noise = np.deg2rad(1.5)
        self.on_step: Callable[[mujoco.MjModel, mujoco.MjData], None] | None = None  # e.g. a recorder

    def reset(self, layout: Layout, robot_q: np.ndarray) -> Observation:
        """The world set up as `layout` places its objects, the arm at joint angles `robot_q`
        (nq,), settled for 0.2 s: its first observation.  Anything else is a one-line
        ConfigError."""
        from lmjx.errors import ConfigError

        if not isinstance(layout, Layout):
            raise ConfigError(f"layout: give an lmjx.Layout (a scenario and its objects' poses), got "
                              f"{type(layout).__name__}")  # fmt: skip
        try:
            q = np.asarray(robot_q, dtype=np.float64) if not isinstance(robot_q, str) else np.array([])
        except (TypeError, ValueError):
            q = np.array([])
        if q.shape != (self.robot.nq,) or not np.all(np.isfinite(q)):
            raise ConfigError(f"robot_q: give the arm's {self.robot.nq} joint angles [rad], finite numbers, "
                              f"got {np.shape(robot_q)}")  # fmt: skip
        robot_q = q
        n = len(layout.scenario.movable)
        self.scene = build_scene(self.robot, layout.scenario, real_physics(self.robot, n, self.rng))
        self.data = mujoco.MjData(self.scene.model)
        self._scratch: mujoco.MjData | None = None  # `_roll`'s
        set_state(self.scene, self.data, robot_q, object_qpos(self.scene, layout.poses))
        for _ in range(round(0.2 / self.scene.model.opt.timestep)):  # let contacts settle
            mujoco.mj_step(self.scene.model, self.data)
        self.time = 0.0
        m = self.scene.model
        robot_bodies = {self.robot.mj.body(b).name for b in range(1, self.robot.mj.nbody)}
        self._robot_geom = np.array([m.body(int(m.geom_bodyid[g])).name in robot_bodies for g in range(m.ngeom)])
        self._object_of = {int(m.geom(f"{b.name}_geom").id): b.name for b in layout.scenario.movable}
        self._fixed_of = {int(m.geom(b.name).id): b.name for b in layout.scenario.fixed}
        self._geoms_of: dict[str, list[int]] = {}
        for g, name in {**self._object_of, **self._fixed_of}.items():
            self._geoms_of.setdefault(name, []).append(g)
        # the arm's geoms that take part in contacts (those `_touching` can see)
        self._arm_geoms = np.flatnonzero(self._robot_geom & ((m.geom_contype != 0) | (m.geom_conaffinity != 0)))
        return self.observe()

    def _touching(self) -> tuple[set[str], set[str]]:
        """Movable objects and fixed obstacles in contact with the arm now."""
        assert self.data is not None
        objects: set[str] = set()
        fixed: set[str] = set()
        if not self.data.ncon:
            return objects, fixed
        pairs = self.data.contact.geom  # (ncon, 2): most are the objects' own, on the table
        arm = self._robot_geom[pairs]
        if not arm.any():
            return objects, fixed
        for b in np.concatenate([pairs[arm[:, 0], 1], pairs[arm[:, 1], 0]]).tolist():
            if b in self._object_of:
                objects.add(self._object_of[b])
            elif b in self._fixed_of:
                fixed.add(self._fixed_of[b])
        return objects, fixed

    def _clear_of(self, names: set[str]) -> set[str]:
        """Those of `names` (objects, obstacles) the arm is at least LEAVE_CLEAR away from now."""
        if not names:
            return set()
        assert self.scene is not None and self.data is not None
        m, d = self.scene.model, self.data
        return {
            n
            for n in names
            if all(
                mujoco.mj_geomDistance(m, d, int(a), b, 2 * LEAVE_CLEAR, None) >= LEAVE_CLEAR
                for a in self._arm_geoms
                for b in self._geoms_of[n]
            )
        }

    def execute(self, action: Action) -> Observation:
        assert self.scene is not None and self.data is not None, "reset first"
        m, d = self.scene.model, self.data
        before = self.truth()[0, :2]
        transit = action.transit_steps * round(CONTROL_DT / m.opt.timestep)  # physics steps before the edge
        # a transit "touches" what it comes into contact with: contacts the arm is already in
        # when it begins (the last edge ended against an object or the table) and leaves are
        # not counted; one it enters again once it has been LEAVE_CLEAR clear of it is
        ledger = TransitContacts(*self._touching())
        u_all = controls(action, m.opt.timestep, self.settle)
        stepwise = len(u_all) if self.on_step is not None else min(transit, len(u_all))
        for i, u in enumerate(u_all[:stepwise]):
            d.ctrl[:] = u
            mujoco.mj_step(m, d)
            if i < transit:
                ledger.update(*(self._touching() if d.ncon else (set(), set())), self._clear_of(ledger.leaving))
            if self.on_step is not None:
                self.on_step(m, d)
        if stepwise < len(u_all):  # the edge and the settling, watched by no one: in C MuJoCo's own loop
            self._roll(u_all[stepwise:])
        touched, hit_fixed, left = ledger.objects, ledger.fixed, ledger.left
        self.time += action.duration + self.settle
        obs = self.observe()
        obs.target_moved_m = float(np.hypot(*(self.truth()[0, :2] - before)))
        names = [b.name for b in self.scene.scenario.movable]
        obs.transit_contacts = tuple(n for n in names if n in touched)
        obs.transit_hit_fixed = bool(hit_fixed)
        obs.transit_left = tuple(sorted(left))
        return obs

    def _roll(self, u: np.ndarray) -> None:
        """Step the world through the controls `u` (steps, nu): all but the last in
        `mujoco.rollout` (the same steps as mj_step one by one, from the whole physics state:
        the same result to the bit, without the interpreter between steps), the last with
        mj_step, which leaves the world's data as the stepwise loop does (its contacts, its
        positions)."""
        assert self.scene is not None and self.data is not None
        m, d = self.scene.model, self.data
        if len(u) > 1:
            spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
            state = np.empty(mujoco.mj_stateSize(m, spec))
            mujoco.mj_getState(m, d, state, spec)
            if self._scratch is None:
                self._scratch = mujoco.MjData(m)
            # (the solver's warm start is no part of the physics state: given and taken back)
            out, _ = rollout.rollout(m, self._scratch, state[None], u[None, :-1],
                                     initial_warmstart=d.qacc_warmstart[None].copy())  # fmt: skip
            mujoco.mj_setState(m, d, out[0, -1], spec)
            d.qacc_warmstart[:] = self._scratch.qacc_warmstart
        d.ctrl[:] = u[-1]
        mujoco.mj_step(m, d)

    def truth(self) -> np.ndarray:
        assert self.scene is not None and self.data is not None
        return read_objects(self.scene, self.data)

    def observe(self) -> Observation:
        assert self.scene is not None and self.data is not None
        true = self.truth()
        est = true.copy()
        est[:, :2] += self.rng.normal(0.0, self.pos_noise, (len(true), 2))
        yaw = quat_yaw(true[:, 3:]) + self.rng.normal(0.0, self.yaw_noise, len(true))
        # the planner re-places what it sees at rest on the table, upright
        est[:, 2] = [b.zc for b in self.scene.scenario.movable]
        est[:, 3] = np.cos(yaw / 2)
        est[:, 4:6] = 0.0
        est[:, 6] = np.sin(yaw / 2)
        upright = np.abs(true[:, 2] - est[:, 2]) < 0.01
        # a cylinder on its side may rest near its upright height: its axis tells (a box's height alone)
        round_ = np.array([b.shape != "box" for b in self.scene.scenario.movable])
        axis_z = 1.0 - 2.0 * (true[:, 4] ** 2 + true[:, 5] ** 2)  # the object's z axis, its world z component
        upright &= ~round_ | (axis_z > UPRIGHT_COS)
        est[~upright, 2] = true[~upright, 2]  # a fallen or lifted object is seen where it is
        return Observation(self.data.qpos[self.scene.robot_qpos].copy(), est, self.time)
