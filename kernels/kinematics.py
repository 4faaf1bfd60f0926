"""Forward kinematics and Jacobians of a `Tree`, for one configuration.

The core works on scalar tuples (see `math3`): a joint angle is either a traced value or a
Python float (a locked joint, folded into the program as a constant).  The `*_array`
functions wrap the core for callers that want plain arrays: `q` (nj,) -> arrays; batch any
of them with `jax.vmap`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from .math3 import (
    Mat,
    Scalar,
    Vec,
    axis_rotation,
    cmat,
    cvec,
    mcol,
    mmul,
    mvec,
    stack_mat,
    stack_vec,
    vadd,
    vcross,
    vsub,
)
from .model import ArmModel, Tree


class Pose(NamedTuple):
    rot: Mat  # R_world_body
    pos: Vec  # p_world_body


class JointFrame(NamedTuple):
    axis: Vec  # joint axis, world frame
    anchor: Vec  # a point on the joint axis, world frame


def body_poses(tree: Tree, q: Sequence[Scalar]) -> list[Pose]:
    """World pose of every body for joint angles `q` (nj scalars)."""
    poses: list[Pose] = []
    for b in range(len(tree.parent)):
        par = int(tree.parent[b])
        r_pb, p_pb = cmat(tree.rot[b]), cvec(tree.pos[b])
        if par < 0:
            rot, pos = r_pb, p_pb
        else:
            parent = poses[par]
            rot = mmul(parent.rot, r_pb)
            pos = vadd(parent.pos, mvec(parent.rot, p_pb))
        j = int(tree.joint[b])
        if j >= 0:
            anchor = cvec(tree.anchor[j])
            anchor_w = vadd(pos, mvec(rot, anchor))
            rot = mmul(rot, axis_rotation(tree.axis[j], q[j]))
            if np.any(tree.anchor[j] != 0):
                pos = vsub(anchor_w, mvec(rot, anchor))
        poses.append(Pose(rot, pos))
    return poses


def joint_frames(tree: Tree, poses: Sequence[Pose]) -> list[JointFrame]:
    """World axis and anchor of every joint."""
    frames = []
    for j in range(len(tree.joint_body)):
        pose = poses[int(tree.joint_body[j])]
        axis = mvec(pose.rot, cvec(tree.axis[j]))
        anchor = vadd(pose.pos, mvec(pose.rot, cvec(tree.anchor[j])))
        frames.append(JointFrame(axis, anchor))
    return frames


def joint_values(free: tuple[int, ...], q_fixed, q_free) -> list[Scalar]:
    """The full joint list from the free variables: `q_free[k]` for free joint free[k]; a
    locked joint's angle as a Python float (folded into the program) when `q_fixed` is
    numpy, or as a traced value when it is a JAX array."""
    pos = {j: k for k, j in enumerate(free)}
    const = isinstance(q_fixed, np.ndarray)
    return [q_free[pos[j]] if j in pos else (float(q_fixed[j]) if const else q_fixed[j]) for j in range(len(q_fixed))]


def point_in_world(pose: Pose, p_body: Vec) -> Vec:
    return vadd(pose.pos, mvec(pose.rot, p_body))


def point_jacobian(
    tree: Tree, frames: Sequence[JointFrame], body: int, p_world: Vec, joints: Sequence[int]
) -> list[Vec]:
    """Columns d p_world / d q_j for j in `joints`, for a point fixed to `body`.

    A joint that does not move the body contributes a constant zero column.
    """
    cols: list[Vec] = []
    for j in joints:
        if tree.ancestors[body, j]:
            f = frames[j]
            cols.append(vcross(f.axis, vsub(p_world, f.anchor)))
        else:
            cols.append((0.0, 0.0, 0.0))
    return cols


def direction_jacobian(tree: Tree, frames: Sequence[JointFrame], body: int, v: Vec, joints: Sequence[int]) -> list[Vec]:
    """Columns d v / d q_j of a direction `v` fixed to `body` (axis_j x v, or zero)."""
    return [vcross(frames[j].axis, v) if tree.ancestors[body, j] else (0.0, 0.0, 0.0) for j in joints]


# ----------------------------------------------------------------------------------------
# Array wrappers (tests, benchmarks, other kernels that want (.., 3) arrays).


def _split(q: jnp.ndarray) -> list[Scalar]:
    return [q[j] for j in range(q.shape[-1])]


def body_poses_array(tree: Tree, q: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """q (nj,) -> R_world_body (nb, 3, 3), p_world_body (nb, 3)."""
    poses = body_poses(tree, _split(q))
    like = q[0]
    return (
        jnp.stack([stack_mat(p.rot, like) for p in poses]),
        jnp.stack([stack_vec(p.pos, like) for p in poses]),
    )


def site_positions_array(arm: ArmModel, q: jnp.ndarray) -> jnp.ndarray:
    """q (nj,) -> world position of every site (ns, 3)."""
    poses = body_poses(arm.tree, _split(q))
    return jnp.stack(
        [stack_vec(point_in_world(poses[int(b)], cvec(arm.site_pos[s])), q[0]) for s, b in enumerate(arm.site_body)]
    )


def site_jacobian_array(arm: ArmModel, q: jnp.ndarray, site: int) -> tuple[jnp.ndarray, jnp.ndarray]:
    """q (nj,) -> translational (3, nj) and rotational (3, nj) Jacobian of a site."""
    tree = arm.tree
    poses = body_poses(tree, _split(q))
    frames = joint_frames(tree, poses)
    body = int(arm.site_body[site])
    p = point_in_world(poses[body], cvec(arm.site_pos[site]))
    nj = len(tree.joint_body)
    cols = point_jacobian(tree, frames, body, p, range(nj))
    jt = jnp.stack([stack_vec(c, q[0]) for c in cols], axis=-1)
    jr = jnp.stack(
        [stack_vec(frames[j].axis if tree.ancestors[body, j] else (0.0, 0.0, 0.0), q[0]) for j in range(nj)],
        axis=-1,
    )
    return jt, jr


def tool_axis(poses: Sequence[Pose], tool_body: int) -> Vec:
    """The tool (approach) axis: the z column of the tool body's rotation."""
    return mcol(poses[tool_body].rot, 2)
