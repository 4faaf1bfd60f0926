"""The robot: loads the Panda MJCF once and exposes everything else derives from it.

`load_robot()` returns a `Robot` holding the compiled MuJoCo model, the static `ArmModel`
the kernels consume (kinematic tree, capsules, checked pairs, sites), joint limits and
the interaction points.  Nothing here computes kinematics; the kernels do.
"""

from __future__ import annotations

import functools
import hashlib
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from .kernels.dynamics import Inertials
from .kernels.math3 import quat_to_mat
from .kernels.model import ArmModel, Tree

MODEL_PATH = Path(__file__).parent / "assets" / "panda.xml"
JOINT_NAMES = tuple(f"joint{i}" for i in range(1, 8))
TOOL_BODY = "hand"
TCP_SITE = "tcp"
TABLE_GEOM = "table"
IP_PREFIX = "ip_"


@dataclass(frozen=True, eq=False)
class Robot:
    """The Panda on its table, as every part of lmjx sees it."""

    path: Path
    name: str  # the MJCF's model name
    model_hash: str  # sha256 of the MJCF text
    mj: mujoco.MjModel
    arm: ArmModel
    joint_names: tuple[str, ...]
    lower: np.ndarray  # (7,) position limits [rad]
    upper: np.ndarray
    qd_max: np.ndarray  # (7,) velocity limits [rad/s]
    qdd_max: np.ndarray  # (7,) acceleration limits [rad/s^2]
    jerk_max: np.ndarray  # (7,) jerk limits [rad/s^3]
    tau_max: np.ndarray  # (7,) torque limits [Nm]
    friction: np.ndarray  # (3, 7) Gaz et al. friction parameters phi1, phi2, phi3
    inertials: Inertials
    ready: np.ndarray  # (7,) Franka's ready pose
    site_names: tuple[str, ...]
    interaction_points: dict[str, int] = field(default_factory=dict)  # name -> site index
    tcp_site: int = 0

    @property
    def nq(self) -> int:
        return len(self.joint_names)

    def site_index(self, name: str) -> int:
        return self.site_names.index(name)


def _numeric(m: mujoco.MjModel, name: str) -> np.ndarray:
    return np.array(m.numeric(name).data, dtype=np.float64)


def _tree(m: mujoco.MjModel) -> Tree:
    nb = m.nbody - 1  # body 0 is the world
    parent = np.array([m.body_parentid[b] - 1 for b in range(1, m.nbody)], dtype=np.int32)
    joint = -np.ones(nb, dtype=np.int32)
    for j in range(m.njnt):
        if m.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
            raise ValueError(f"joint {m.joint(j).name}: lmjx supports hinge joints only")
        b = m.jnt_bodyid[j] - 1
        if joint[b] >= 0:
            raise ValueError(f"body {m.body(b + 1).name} has more than one joint")
        joint[b] = j
    rot = np.stack([quat_to_mat(m.body_quat[b]) for b in range(1, m.nbody)])
    pos = np.array(m.body_pos[1:], dtype=np.float64)
    axis = np.array(m.jnt_axis, dtype=np.float64)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    anchor = np.array(m.jnt_pos, dtype=np.float64)
    joint_body = np.array(m.jnt_bodyid - 1, dtype=np.int32)
    ancestors = np.zeros((nb, m.njnt))
    for b in range(nb):
        a = b
        while a >= 0:
            if joint[a] >= 0:
                ancestors[b, joint[a]] = 1.0
            a = parent[a]
    return Tree(parent, joint, pos, rot, axis, anchor, joint_body, ancestors)


def _inertials(m: mujoco.MjModel) -> Inertials:
    """Mass, COM and inertia tensor (body frame) of every body but the world."""
    inertia = []
    for b in range(1, m.nbody):
        r = quat_to_mat(m.body_iquat[b])
        inertia.append(r @ np.diag(m.body_inertia[b]) @ r.T)
    return Inertials(
        mass=np.array(m.body_mass[1:], dtype=np.float64),
        com=np.array(m.body_ipos[1:], dtype=np.float64),
        inertia=np.array(inertia),
        gravity=np.array(m.opt.gravity, dtype=np.float64),
    )


def _pair_is_checked(m: mujoco.MjModel, g1: int, g2: int) -> bool:
    """Whether C MuJoCo's broad-phase filters would let geoms g1, g2 collide."""
    b1, b2 = m.geom_bodyid[g1], m.geom_bodyid[g2]
    w1, w2 = m.body_weldid[b1], m.body_weldid[b2]
    if w1 == w2:
        return False
    if not (m.geom_contype[g1] & m.geom_conaffinity[g2] or m.geom_contype[g2] & m.geom_conaffinity[g1]):
        return False
    filter_parent = not (m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT)
    if filter_parent and w1 != 0 and w2 != 0:
        p1 = m.body_weldid[m.body_parentid[w1]]
        p2 = m.body_weldid[m.body_parentid[w2]]
        if p1 == w2 or p2 == w1:
            return False
    lo, hi = sorted((int(b1), int(b2)))
    signatures = set(int(s) for s in m.exclude_signature)
    return ((lo << 16) + hi) not in signatures


def _arm_model(m: mujoco.MjModel) -> ArmModel:
    tree = _tree(m)
    caps = [g for g in range(m.ngeom) if m.geom_bodyid[g] != 0 and (m.geom_contype[g] or m.geom_conaffinity[g])]
    for g in caps:
        if m.geom_type[g] != mujoco.mjtGeom.mjGEOM_CAPSULE:
            raise ValueError(f"robot collision geom {m.geom(g).name} must be a capsule")
    cap_body = np.array([m.geom_bodyid[g] - 1 for g in caps], dtype=np.int32)
    rot = [quat_to_mat(m.geom_quat[g]) for g in caps]
    half = np.array([m.geom_size[g][1] for g in caps])
    centre = np.array([m.geom_pos[g] for g in caps])
    axis = np.array([r[:, 2] for r in rot])
    cap_a = centre - axis * half[:, None]
    cap_b = centre + axis * half[:, None]
    cap_r = np.array([m.geom_size[g][0] for g in caps])
    pairs = np.array(
        [(i, j) for i in range(len(caps)) for j in range(i + 1, len(caps)) if _pair_is_checked(m, caps[i], caps[j])],
        dtype=np.int32,
    ).reshape(-1, 2)
    table = m.geom(TABLE_GEOM)
    table_caps = np.array([i for i, g in enumerate(caps) if _pair_is_checked(m, g, table.id)], dtype=np.int32)
    table_z = float(table.pos[2] + table.size[2])
    return ArmModel(
        tree=tree,
        lower=np.array(m.jnt_range[:, 0]),
        upper=np.array(m.jnt_range[:, 1]),
        site_body=np.array(m.site_bodyid - 1, dtype=np.int32),
        site_pos=np.array(m.site_pos, dtype=np.float64),
        site_radius=np.array(m.site_size[:, 0], dtype=np.float64),
        tool_body=int(m.body(TOOL_BODY).id - 1),
        cap_body=cap_body,
        cap_a=cap_a,
        cap_b=cap_b,
        cap_r=cap_r,
        self_pairs=pairs,
        table_caps=table_caps,
        table_z=table_z,
        table_center=np.array(table.pos, dtype=np.float64),
        table_rot=quat_to_mat(table.quat),
        table_half=np.array(table.size, dtype=np.float64),
    )


@functools.lru_cache(maxsize=4)
def load_robot(path: str | Path = MODEL_PATH) -> Robot:
    """Load and cache the robot described by the MJCF at `path` (default: the Panda)."""
    path = Path(path)
    text = path.read_bytes()
    m = mujoco.MjModel.from_xml_path(str(path))
    names = tuple(m.joint(j).name for j in range(m.njnt))
    if names != JOINT_NAMES:
        raise ValueError(f"{path}: expected joints {JOINT_NAMES}, found {names}")
    site_names = tuple(m.site(s).name for s in range(m.nsite))
    ips = {n[len(IP_PREFIX) :]: i for i, n in enumerate(site_names) if n.startswith(IP_PREFIX)}
    return Robot(
        path=path,
        name=ET.fromstring(text).get("model", ""),
        model_hash=hashlib.sha256(text).hexdigest(),
        mj=m,
        arm=_arm_model(m),
        joint_names=names,
        lower=np.array(m.jnt_range[:, 0]),
        upper=np.array(m.jnt_range[:, 1]),
        qd_max=_numeric(m, "lmjx_qd_max"),
        qdd_max=_numeric(m, "lmjx_qdd_max"),
        jerk_max=_numeric(m, "lmjx_jerk_max"),
        tau_max=_numeric(m, "lmjx_tau_max"),
        friction=np.stack([_numeric(m, f"lmjx_friction_phi{i}") for i in (1, 2, 3)]),
        ready=_numeric(m, "lmjx_ready"),
        inertials=_inertials(m),
        site_names=site_names,
        interaction_points=ips,
        tcp_site=site_names.index(TCP_SITE),
    )
