"""The baselines lmjx is measured against: pytorch_kinematics and PyBullet.

Both are optional (extra 'baselines'); the functions raise `BaselineMissingError` with the install
command when a package is absent.  pytorch_kinematics loads lmjx's own MJCF (same model);
PyBullet uses its own bundled Panda URDF (the paper's stack).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from lmjx.model.robot import Robot


class BaselineMissingError(RuntimeError):
    """An optional baseline package is not installed."""


def pk_chain(robot: Robot, end_site: str = "tcp", device: str = "cpu", dtype: str = "float64"):
    """A pytorch_kinematics SerialChain of lmjx's MJCF from the world to `end_site`.

    Works around pytorch_kinematics 0.10.0 with mujoco 3.17, whose joint-type map is keyed
    by MuJoCo's enum values, which do not compare equal to the model's int32 joint types.
    """
    try:
        import pytorch_kinematics as pk
        import pytorch_kinematics.mjcf as pk_mjcf
        import torch
    except ImportError as e:
        msg = f"pytorch_kinematics is not installed ({e}); pip install 'lmjx[baselines]'"
        raise BaselineMissingError(msg) from None
    pk_mjcf.JOINT_TYPE_MAP = {int(k): v for k, v in pk_mjcf.JOINT_TYPE_MAP.items()}
    chain = pk.build_chain_from_mjcf(robot.path.read_text())
    serial = pk.SerialChain(chain, end_site)
    return serial.to(dtype=getattr(torch, dtype), device=device)


@dataclass
class PyBulletPanda:
    client: int
    robot: int
    ee_link: int
    joints: list[int]
    lower: np.ndarray
    upper: np.ndarray


def pybullet_panda() -> PyBulletPanda:
    """PyBullet's own Panda (pybullet_data/franka_panda/panda.urdf) in a DIRECT client."""
    try:
        import pybullet as p
        import pybullet_data
    except ImportError as e:
        raise BaselineMissingError(f"PyBullet is not installed ({e}); pip install 'lmjx[baselines]'") from None
    client = p.connect(p.DIRECT)
    p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client)
    rid = p.loadURDF("franka_panda/panda.urdf", useFixedBase=True, physicsClientId=client)
    joints, lower, upper, ee = [], [], [], -1
    for j in range(p.getNumJoints(rid, physicsClientId=client)):
        info = p.getJointInfo(rid, j, physicsClientId=client)
        if info[2] == p.JOINT_REVOLUTE:
            joints.append(j)
            lower.append(info[8])
            upper.append(info[9])
        if info[12].decode() == "panda_grasptarget":
            ee = j
    return PyBulletPanda(client, rid, ee, joints, np.array(lower), np.array(upper))


def pybullet_ik_loop(
    panda: PyBulletPanda, targets: np.ndarray, q0: np.ndarray, iterations: int, tol: float = 0.002
) -> tuple[float, float]:
    """Solve each target (TCP straight down) serially with calculateInverseKinematics.

    Returns (seconds, success fraction); success = grasp target within `tol` of the target,
    checked by PyBullet's own forward kinematics (outside the timed loop).
    """
    import pybullet as p

    down = p.getQuaternionFromEuler([np.pi, 0.0, 0.0])
    sols = []
    t0 = time.perf_counter()
    for tgt, q in zip(targets, q0, strict=True):
        for j, v in zip(panda.joints, q, strict=True):
            p.resetJointState(panda.robot, j, float(v), physicsClientId=panda.client)
        sols.append(
            p.calculateInverseKinematics(
                panda.robot,
                panda.ee_link,
                [float(x) for x in tgt],
                down,
                maxNumIterations=iterations,
                residualThreshold=1e-5,
                physicsClientId=panda.client,
            )
        )
    seconds = time.perf_counter() - t0
    ok = 0
    for tgt, sol in zip(targets, sols, strict=True):
        for j, v in zip(panda.joints, sol[: len(panda.joints)], strict=True):
            p.resetJointState(panda.robot, j, float(v), physicsClientId=panda.client)
        pos = np.array(
            p.getLinkState(panda.robot, panda.ee_link, computeForwardKinematics=True, physicsClientId=panda.client)[4]
        )
        ok += float(np.linalg.norm(pos - tgt) <= tol)
    return seconds, ok / max(1, len(targets))
