"""MuJoCo models of the robot with a scenario's objects, for the planner's simulator and for
the simulated "real" world.

`build_scene` adds the scenario's objects to the robot's MJCF (lmjx/model/assets/panda.xml, ur5e.xml or a
user's) through MjSpec: movable boxes and cylinders as free bodies (a box or cylinder geom of
the object's mass and friction), the fixed ones (the tunnel) as static geoms, the goal region
as a marking without collisions.  `Physics` holds everything that may differ between the
planner's simulator and the "real" world: friction, masses, the robot's collision radii,
the joint servos, the time step.  Nothing here plans or decides.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from lmjx.model.robot import Robot
from lmjx.sim.scenarios import GOAL_RGBA, Box, Scenario

# Contact groups (contype, conaffinity); MuJoCo lets two geoms touch when either's contype
# meets the other's conaffinity.  The robot touches the objects and the fixed obstacles, not
# itself; the table touches the objects, and the robot only where Physics asks for it.
ROBOT_BITS = (1, 0)
OBJECT_BITS = (2, 3)
STATIC_BITS = (2, 3)
TABLE_BITS = {True: (2, 3), False: (2, 2)}
GEOM_TYPES = {"box": mujoco.mjtGeom.mjGEOM_BOX, "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER}  # by `Box.shape`


@dataclass(frozen=True)
class Physics:
    """Physical parameters of one simulated world."""

    timestep: float = 0.005  # [s]
    robot_friction: float = 0.8
    # The objects' and the table's sliding frictions are the scenario's (`Box.friction`,
    # `Scenario.table_friction`; MuJoCo takes the larger of a touching pair's), times these:
    friction_scale: tuple[float, ...] = ()  # per movable object; () = all 1
    table_friction_scale: float = 1.0
    mass_scale: tuple[float, ...] = ()  # per movable object; () = all 1
    robot_radius_offset: float = 0.0  # added to every robot capsule radius [m]
    # Joint servos: tau = kp (q* - q) + kv (qd* - qd), clipped to +-servo_force; the
    # trajectory gives q* and qd* (velocity feedforward, as Franka's joint controller).  One
    # value per joint, or a single value for every joint.
    servo_kp: tuple[float, ...] = (5000.0,)  # [Nm/rad]
    servo_kv: tuple[float, ...] = (300.0,)  # [Nm s/rad]
    servo_force: tuple[float, ...] | None = None  # torque limits; None: unlimited (near-exact playback)
    armature: float = 0.1  # reflected motor inertia per joint [kg m^2] (keeps stiff servos stable)
    # The planner's arm paths are free of table contact already (edges and transits are
    # checked); the "real" world keeps robot-table contacts.
    robot_table_contacts: bool = False


@dataclass
class Scene:
    """A compiled scene and where its parts live in the state vectors."""

    model: mujoco.MjModel
    scenario: Scenario
    physics: Physics
    robot_qpos: np.ndarray = field(repr=False)  # (nq,) qpos addresses of the robot joints
    robot_dof: np.ndarray = field(repr=False)  # (nq,) dof addresses
    obj_qpos: np.ndarray = field(repr=False)  # (n,) qpos address of each movable object's free joint
    obj_dof: np.ndarray = field(repr=False)
    obj_body: np.ndarray = field(repr=False)  # (n,) body ids
    obj_half: np.ndarray = field(repr=False)  # (n, 3) half sizes (a cylinder's: its circumscribing box's)

    @property
    def n_objects(self) -> int:
        return len(self.obj_qpos)


def geom_size(b: Box) -> list[float]:
    """MuJoCo's size of an object's geom: a box's half sizes, a cylinder's radius and half
    height (its axis along the geom's z)."""
    return list(b.half) if b.shape == "box" else [b.half[0], b.half[2], 0.0]


def yaw_quat(yaw: float) -> np.ndarray:
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


def quat_yaw(quat: np.ndarray) -> np.ndarray:
    """Yaw (rotation about z) of (..., 4) w, x, y, z quaternions."""
    w, x, y, z = np.moveaxis(np.asarray(quat), -1, 0)
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def per_joint(values: tuple[float, ...], nq: int, what: str) -> tuple[float, ...]:
    """`values` for each of nq joints: one value per joint, or one value for all."""
    if len(values) == 1:
        return tuple(values) * nq
    if len(values) != nq:
        raise ValueError(f"{what}: {len(values)} values for a robot of {nq} joints")
    return tuple(values)


def build_scene(robot: Robot, sc: Scenario, physics: Physics | None = None, fuse_static: bool = False) -> Scene:
    """The robot with a scenario's objects.  `fuse_static` merges bodies without joints into
    their parents (MuJoCo's `fusestatic`): the same rigid bodies and the same physics in a
    shallower tree, which MuJoCo Warp walks level by level."""
    physics = physics or Physics()
    spec = mujoco.MjSpec.from_file(str(robot.path))
    spec.compiler.fusestatic = fuse_static
    robot_bodies = {robot.mj.body(b).name for b in range(1, robot.mj.nbody)}
    spec.option.timestep = physics.timestep
    # Contact groups: the robot touches the table, the fixed obstacles and the objects, but not
    # itself (its trajectories are already free of self-collision); objects touch everything.
    for g in spec.geoms:
        if g.name == "table":
            g.friction = [sc.table_friction * physics.table_friction_scale, 0.005, 0.0001]
            g.contype, g.conaffinity = TABLE_BITS[physics.robot_table_contacts]
        elif g.type == mujoco.mjtGeom.mjGEOM_CAPSULE:
            g.friction = [physics.robot_friction, 0.005, 0.0001]
            g.contype, g.conaffinity = ROBOT_BITS
            if physics.robot_radius_offset:
                g.size = [g.size[0] + physics.robot_radius_offset, g.size[1], g.size[2]]
    unlimited = physics.servo_force is None
    kp = per_joint(physics.servo_kp, robot.nq, "servo_kp")
    kv = per_joint(physics.servo_kv, robot.nq, "servo_kv")
    force = None if unlimited else per_joint(physics.servo_force, robot.nq, "servo_force")
    for i, a in enumerate(list(spec.actuators)):
        a.gainprm[0] = kp[i]
        a.biasprm[1] = -kp[i]
        a.biasprm[2] = 0.0
        a.forcelimited = mujoco.mjtLimited.mjLIMITED_FALSE
        v = spec.add_actuator(name=f"velocity{i + 1}", target=a.target, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        v.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        v.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        v.gainprm[0] = kv[i]
        v.biasprm[2] = -kv[i]
        v.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
    for b in spec.bodies:
        if b.name in robot_bodies:
            b.gravcomp = 1.0  # the joint controller compensates gravity, as Franka's does
    for i, j in enumerate(spec.joints):
        j.armature = physics.armature
        if unlimited:
            j.actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE
        else:
            j.actfrclimited = mujoco.mjtLimited.mjLIMITED_TRUE
            j.actfrcrange = [-force[i], force[i]]
    movable = sc.movable
    fs = physics.friction_scale or (1.0,) * len(movable)
    ms = physics.mass_scale or (1.0,) * len(movable)
    for k, b in enumerate(movable):
        body = spec.worldbody.add_body(name=b.name, pos=[b.x, b.y, b.zc], quat=list(yaw_quat(b.yaw)))
        body.add_freejoint(name=f"{b.name}_free")
        body.add_geom(
            name=f"{b.name}_geom",
            type=GEOM_TYPES[b.shape],
            size=geom_size(b),
            rgba=list(b.rgba),
            mass=b.mass * ms[k],
            friction=[b.friction * fs[k], 0.005, 0.0001],
            condim=3,
            contype=OBJECT_BITS[0],
            conaffinity=OBJECT_BITS[1],
        )
    for b in sc.fixed:
        spec.worldbody.add_geom(
            name=b.name,
            type=GEOM_TYPES[b.shape],
            size=geom_size(b),
            pos=[b.x, b.y, b.zc],
            quat=list(yaw_quat(b.yaw)),
            rgba=list(b.rgba),
            friction=[b.friction, 0.005, 0.0001],
            contype=STATIC_BITS[0],
            conaffinity=STATIC_BITS[1],
        )
    spec.worldbody.add_geom(
        name="goal",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[sc.goal_half[0], sc.goal_half[1], 0.0005],
        pos=[sc.goal_center[0], sc.goal_center[1], 0.0005],
        rgba=list(GOAL_RGBA),
        contype=0,
        conaffinity=0,
    )
    model = spec.compile()
    robot_joints = [model.joint(n) for n in robot.joint_names]
    obj_joints = [model.joint(f"{b.name}_free") for b in movable]
    return Scene(
        model=model,
        scenario=sc,
        physics=physics,
        robot_qpos=np.array([j.qposadr[0] for j in robot_joints]),
        robot_dof=np.array([j.dofadr[0] for j in robot_joints]),
        obj_qpos=np.array([j.qposadr[0] for j in obj_joints]),
        obj_dof=np.array([j.dofadr[0] for j in obj_joints]),
        obj_body=np.array([model.body(b.name).id for b in movable]),
        obj_half=np.array([b.half for b in movable]),
    )


def object_qpos(scene: Scene, poses: np.ndarray) -> np.ndarray:
    """(n, 7) free-joint qpos (x, y, z, quaternion) of objects resting at (x, y, yaw)."""
    out = np.zeros((len(poses), 7))
    out[:, 0:2] = poses[:, :2]
    out[:, 2] = [b.zc for b in scene.scenario.movable]
    out[:, 3:] = np.stack([yaw_quat(y) for y in poses[:, 2]])
    return out


def set_state(scene: Scene, data: mujoco.MjData, robot_q: np.ndarray, obj_qpos: np.ndarray) -> None:
    """Robot at rest at `robot_q` with its servos holding it; objects at rest at `obj_qpos` (n, 7)."""
    data.qpos[:] = 0
    data.qvel[:] = 0
    data.act[:] = 0
    data.qpos[scene.robot_qpos] = robot_q
    for k, adr in enumerate(scene.obj_qpos):
        data.qpos[adr : adr + 7] = obj_qpos[k]
    nq = len(scene.robot_qpos)
    data.ctrl[:nq] = robot_q
    data.ctrl[nq:] = 0.0
    mujoco.mj_forward(scene.model, data)


def read_objects(scene: Scene, data: mujoco.MjData) -> np.ndarray:
    """(n, 7) free-joint qpos of every movable object."""
    return np.stack([data.qpos[a : a + 7] for a in scene.obj_qpos])
