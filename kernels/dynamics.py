"""Inverse dynamics (recursive Newton-Euler) and joint friction, for one state.

tau = M(q) qdd + C(q, qd) qd + g(q), computed by the recursive Newton-Euler algorithm on the
world-frame body poses of `kinematics.body_poses`, with each body's mass, centre of mass
and inertia tensor from the MJCF; plus the joint friction model of Gaz et al. (RA-L 2019),
    f_i(qd) = phi1 / (1 + exp(-phi2 (qd + phi3))) - phi1 / (1 + exp(-phi2 phi3)).
Written on scalar tuples (see `math3`); joint values may be Python floats (locked joints).
Pure functions; batch with `jax.vmap`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from .kinematics import Pose, body_poses, joint_frames
from .math3 import Scalar, Vec, add, cmat, cvec, mtvec, mvec, vadd, vcross, vdot, vscale, vsub
from .model import Tree


class Inertials(NamedTuple):
    """Rigid-body inertia of every body of a `Tree` (numpy constants)."""

    mass: np.ndarray  # (nb,) [kg]
    com: np.ndarray  # (nb, 3) centre of mass in the body frame [m]
    inertia: np.ndarray  # (nb, 3, 3) inertia tensor about the COM, body frame [kg m^2]
    gravity: np.ndarray  # (3,) world gravity [m/s^2]


def rnea(
    tree: Tree,
    inertials: Inertials,
    q: Sequence[Scalar],
    qd: Sequence[Scalar],
    qdd: Sequence[Scalar],
    poses: Sequence[Pose] | None = None,
) -> list[Scalar]:
    """Joint torques (nj scalars) that produce accelerations `qdd` at state (q, qd).

    Joints must rotate about their body's origin (MJCF joint pos 0): docs/ROBOTS.md asks it of every robot.
    `poses` (from `body_poses(tree, q)`) may be passed in to share the forward kinematics.
    """
    if np.any(tree.anchor != 0):
        raise ValueError("rnea supports hinge joints through the body origin only")
    poses = poses if poses is not None else body_poses(tree, q)
    frames = joint_frames(tree, poses)
    nb = len(tree.parent)
    zero: Vec = (0.0, 0.0, 0.0)
    g = cvec(inertials.gravity)
    omega: list[Vec] = []
    alpha: list[Vec] = []
    acc: list[Vec] = []  # linear acceleration of each body origin, gravity included
    for b in range(nb):
        par = int(tree.parent[b])
        if par < 0:
            w_p, dw_p = zero, zero
            a_b = vscale(-1.0, g)  # the world accelerates upward at g: gravity as an inertial force
        else:
            w_p, dw_p = omega[par], alpha[par]
            r = vsub(poses[b].pos, poses[par].pos)
            a_b = vadd(acc[par], vadd(vcross(dw_p, r), vcross(w_p, vcross(w_p, r))))
        j = int(tree.joint[b])
        if j >= 0:
            z = frames[j].axis
            zqd = vscale(qd[j], z)
            w_b = vadd(w_p, zqd)
            dw_b = vadd(dw_p, vadd(vscale(qdd[j], z), vcross(w_p, zqd)))
        else:
            w_b, dw_b = w_p, dw_p
        omega.append(w_b)
        alpha.append(dw_b)
        acc.append(a_b)

    force: list[Vec] = [zero] * nb  # force on body b from its parent
    moment: list[Vec] = [zero] * nb  # moment on body b from its parent, about b's origin
    tau: list[Scalar] = [0.0] * len(tree.joint_body)
    for b in reversed(range(nb)):
        rot = poses[b].rot
        r = mvec(rot, cvec(inertials.com[b]))  # origin -> COM, world frame
        a_c = vadd(acc[b], vadd(vcross(alpha[b], r), vcross(omega[b], vcross(omega[b], r))))
        m = float(inertials.mass[b])
        inertia = cmat(inertials.inertia[b])

        def i_world(v: Vec, rot: tuple = rot, inertia: tuple = inertia) -> Vec:
            return mvec(rot, mvec(inertia, mtvec(rot, v)))

        f_body = vscale(m, a_c)
        n_body = vadd(i_world(alpha[b]), vcross(omega[b], i_world(omega[b])))
        force[b] = vadd(force[b], f_body)
        moment[b] = vadd(moment[b], vadd(n_body, vcross(r, f_body)))
        j = int(tree.joint[b])
        if j >= 0:
            tau[j] = vdot(frames[j].axis, moment[b])
        par = int(tree.parent[b])
        if par >= 0:
            d = vsub(poses[b].pos, poses[par].pos)
            force[par] = vadd(force[par], force[b])
            moment[par] = vadd(moment[par], vadd(moment[b], vcross(d, force[b])))
    return tau


def friction(phi: np.ndarray, qd: Sequence[Scalar]) -> list[Scalar]:
    """Gaz et al. joint friction f_i(qd_i); phi is (3, nj): phi1, phi2, phi3."""
    out: list[Scalar] = []
    for i, v in enumerate(qd):
        p1, p2, p3 = (float(x) for x in phi[:, i])
        offset = p1 / (1.0 + np.exp(-p2 * p3))
        if isinstance(v, float):
            out.append(p1 / (1.0 + float(np.exp(-p2 * (v + p3)))) - offset)
        else:
            out.append(add(p1 / (1.0 + jnp.exp(-p2 * (v + p3))), -offset))
    return out


def inverse_dynamics_with_friction(
    tree: Tree,
    inertials: Inertials,
    phi: np.ndarray,
    q: Sequence[Scalar],
    qd: Sequence[Scalar],
    qdd: Sequence[Scalar],
    poses: Sequence[Pose] | None = None,
) -> list[Scalar]:
    """tau = M qdd + C qd + g + f(qd): the motor torques the move needs."""
    tau = rnea(tree, inertials, q, qd, qdd, poses)
    return [add(t, f) for t, f in zip(tau, friction(phi, qd), strict=True)]
