"""Clearances between the arm's capsules, the table and a box (or an upright cylinder), for
one configuration.

Clearance is a signed distance in metres: positive means apart, negative means penetration
(C MuJoCo reports a contact exactly when it is negative).  Vectors are scalar tuples (see
`math3`) whose entries are arrays over capsules or capsule pairs.  Pure functions; batch
with `jax.vmap`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .kinematics import Pose, body_poses, point_in_world
from .math3 import Mat, Vec, cmat, cvec, mtvec, to_array, vsub
from .model import ArmModel

_EPS = 1e-12


def capsule_endpoints(arm: ArmModel, poses: Sequence[Pose], caps: Sequence[int], like: jnp.ndarray) -> tuple[Vec, Vec]:
    """World endpoints of capsules `caps`: two vectors whose entries are (len(caps),) arrays."""
    ends_a = [point_in_world(poses[int(arm.cap_body[c])], cvec(arm.cap_a[c])) for c in caps]
    ends_b = [point_in_world(poses[int(arm.cap_body[c])], cvec(arm.cap_b[c])) for c in caps]

    def gather(ends: list[Vec]) -> Vec:
        return tuple(jnp.stack([to_array(e[k], like) for e in ends], axis=-1) for k in range(3))  # type: ignore[return-value]

    return gather(ends_a), gather(ends_b)


def segment_distance(p1: Vec, q1: Vec, p2: Vec, q2: Vec) -> jnp.ndarray:
    """Distance between segments [p1, q1] and [p2, q2] (closest points; Ericson 5.1.9)."""
    d1 = vsub(q1, p1)
    d2 = vsub(q2, p2)
    r = vsub(p1, p2)

    def dot(u: Vec, v: Vec) -> jnp.ndarray:
        return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]

    a_raw = dot(d1, d1)
    e_raw = dot(d2, d2)
    a = jnp.maximum(a_raw, _EPS)
    e = jnp.maximum(e_raw, _EPS)
    f = dot(d2, r)
    c = dot(d1, r)
    b = dot(d1, d2)
    denom = a * e - b * b
    s = jnp.where(denom > 1e-9 * a * e, jnp.clip((b * f - c * e) / jnp.maximum(denom, _EPS), 0.0, 1.0), 0.0)
    t = (b * s + f) / e
    s = jnp.where(t < 0.0, jnp.clip(-c / a, 0.0, 1.0), jnp.where(t > 1.0, jnp.clip((b - c) / a, 0.0, 1.0), s))
    t = jnp.clip(t, 0.0, 1.0)
    # Degenerate segments (points): the closest point on the other segment.
    first_point = a_raw <= _EPS
    second_point = e_raw <= _EPS
    s = jnp.where(first_point, 0.0, jnp.where(second_point, jnp.clip(-c / a, 0.0, 1.0), s))
    t = jnp.where(second_point, 0.0, jnp.where(first_point, jnp.clip(f / e, 0.0, 1.0), t))
    dx = (p1[0] + d1[0] * s) - (p2[0] + d2[0] * t)
    dy = (p1[1] + d1[1] * s) - (p2[1] + d2[1] * t)
    dz = (p1[2] + d1[2] * s) - (p2[2] + d2[2] * t)
    return jnp.sqrt(dx * dx + dy * dy + dz * dz)


def self_clearance(arm: ArmModel, a_w: Vec, b_w: Vec) -> jnp.ndarray:
    """(np,) surface distance of every checked capsule pair; a_w, b_w over all capsules."""
    i, j = arm.self_pairs[:, 0], arm.self_pairs[:, 1]
    dist = segment_distance(
        tuple(x[..., i] for x in a_w),  # type: ignore[arg-type]
        tuple(x[..., i] for x in b_w),  # type: ignore[arg-type]
        tuple(x[..., j] for x in a_w),  # type: ignore[arg-type]
        tuple(x[..., j] for x in b_w),  # type: ignore[arg-type]
    )
    r = np.asarray(arm.cap_r)
    return dist - (r[i] + r[j]).astype(np.float32)


def box_sdf(p: Vec, half: Sequence[float]) -> jnp.ndarray:
    """Signed distance of points `p`, given in a box's frame, to the box of half sizes `half`."""
    qx = jnp.abs(p[0]) - half[0]
    qy = jnp.abs(p[1]) - half[1]
    qz = jnp.abs(p[2]) - half[2]
    ox, oy, oz = jnp.maximum(qx, 0.0), jnp.maximum(qy, 0.0), jnp.maximum(qz, 0.0)
    outside = jnp.sqrt(ox * ox + oy * oy + oz * oz)
    inside = jnp.minimum(jnp.maximum(jnp.maximum(qx, qy), qz), 0.0)
    return outside + inside


def cylinder_sdf(p: Vec, radius: jnp.ndarray | float, half_height: jnp.ndarray | float) -> jnp.ndarray:
    """Signed distance of points `p`, given in a cylinder's frame (its axis z, its centre the
    origin), to the solid cylinder of `radius` and half height `half_height`."""
    dr = jnp.sqrt(p[0] * p[0] + p[1] * p[1]) - radius
    dz = jnp.abs(p[2]) - half_height
    o_r, o_z = jnp.maximum(dr, 0.0), jnp.maximum(dz, 0.0)
    return jnp.sqrt(o_r * o_r + o_z * o_z) + jnp.minimum(jnp.maximum(dr, dz), 0.0)


def capsule_box_clearance(
    a_w: Vec,
    b_w: Vec,
    radius: jnp.ndarray | np.ndarray,
    center: Vec,
    rot: Mat,
    half: Sequence[float],
    iters: int = 24,
    unroll: bool = True,
    cylinders: bool = False,
) -> jnp.ndarray:
    """Signed distance between capsules [a_w, b_w] of `radius` and a box (centre, R_world_box).

    The box's signed distance is convex, so along a segment it is a convex function of the
    segment parameter: a golden-section search (one new evaluation per step) finds its
    minimum; 24 steps shrink the bracket to 1e-5 of the segment, and the distance error is
    smaller still, the function being flat (or, at a box edge, of slope <= 1) there.
    `cylinders` (static): a box whose y half size is negative is an upright cylinder of
    radius half[0] and half height half[2] about the box's z axis, its exact signed distance
    (`cylinder_sdf`, convex too) taken instead; False traces the boxes' program alone.
    """
    a_l = mtvec(rot, vsub(a_w, center))
    b_l = mtvec(rot, vsub(b_w, center))
    d = vsub(b_l, a_l)

    def f(t: jnp.ndarray) -> jnp.ndarray:
        p = (a_l[0] + d[0] * t, a_l[1] + d[1] * t, a_l[2] + d[2] * t)
        if cylinders:
            return jnp.where(half[1] < 0, cylinder_sdf(p, half[0], half[2]), box_sdf(p, half))
        return box_sdf(p, half)

    g = 0.6180339887498949
    zero = jnp.zeros_like(a_l[0] + d[0])
    lo, hi = zero, zero + 1.0
    m1, m2 = hi - g, lo + g
    f1, f2 = f(m1), f(m2)

    def body(_: int, state: tuple[jnp.ndarray, ...]) -> tuple[jnp.ndarray, ...]:
        lo, hi, m1, m2, f1, f2 = state
        left = f1 <= f2  # the minimum lies in [lo, m2]; else in [m1, hi]
        lo, hi = jnp.where(left, lo, m1), jnp.where(left, m2, hi)
        t = jnp.where(left, hi - g * (hi - lo), lo + g * (hi - lo))
        ft = f(t)
        m1, m2, f1, f2 = (
            jnp.where(left, t, m2),
            jnp.where(left, m1, t),
            jnp.where(left, ft, f2),
            jnp.where(left, f1, ft),
        )
        return lo, hi, m1, m2, f1, f2

    state = (lo, hi, m1, m2, f1, f2)
    if unroll:  # the search fuses into the surrounding kernel
        for i in range(iters):
            state = body(i, state)
    else:
        state = jax.lax.fori_loop(0, iters, body, state)
    lo, hi, m1, m2, f1, f2 = state
    best = jnp.minimum(jnp.minimum(f1, f2), jnp.minimum(f(zero), f(zero + 1.0)))
    return best - radius


def table_clearance(arm: ArmModel, a_w: Vec, b_w: Vec, unroll: bool = True) -> jnp.ndarray:
    """(nt,) exact signed distance of each table-checked capsule to the table box.

    a_w, b_w hold the endpoints of the capsules `arm.table_caps`, in that order.
    """
    return capsule_box_clearance(
        a_w,
        b_w,
        np.asarray(arm.cap_r[arm.table_caps], np.float32),
        cvec(arm.table_center),
        cmat(arm.table_rot),
        [float(h) for h in arm.table_half],
        unroll=unroll,
    )


class ArmClearance(NamedTuple):
    """Clearances of one configuration: smallest over capsule pairs and over capsules-table."""

    self_clearance: jnp.ndarray  # [m], +inf when no pair is checked
    table_clearance: jnp.ndarray  # [m]


def arm_clearance(arm: ArmModel, q: jnp.ndarray, unroll: bool = True) -> ArmClearance:
    """Self and table clearance of the arm at joint angles q (nj,): what C MuJoCo's collision
    pass over the robot model tests (its contacts exist exactly where one is negative)."""
    poses = body_poses(arm.tree, [q[j] for j in range(q.shape[0])])
    caps = list(range(len(arm.cap_r)))
    a_w, b_w = capsule_endpoints(arm, poses, caps, q[0])
    tab = np.asarray(arm.table_caps)
    table = jnp.min(
        table_clearance(arm, tuple(x[tab] for x in a_w), tuple(x[tab] for x in b_w), unroll), initial=jnp.inf
    )
    selfc = jnp.min(self_clearance(arm, a_w, b_w)) if len(arm.self_pairs) else jnp.asarray(jnp.inf, q.dtype)
    return ArmClearance(selfc, table)


class BoxClearance(NamedTuple):
    """Clearance of one configuration to each box of a scene (the arm's capsules' smallest)."""

    box_clearance: jnp.ndarray  # (nb,) [m]


def boxes_clearance(
    arm: ArmModel,
    q: jnp.ndarray,
    centers: jnp.ndarray,
    rots: jnp.ndarray,
    halves: jnp.ndarray,
    unroll: bool = True,
    cylinders: bool = False,
) -> BoxClearance:
    """Signed distance from the arm at joint angles q (nj,) to each of nb boxes (centres
    (nb, 3), world-from-box rotations (nb, 3, 3), half sizes (nb, 3); all traced, so one
    program serves any scene of nb boxes): the smallest over the arm's capsules.  A padding
    box far away (or of zero size) is harmless.  `cylinders` (static): rows of halves with a
    negative y half size are upright cylinders (`capsule_box_clearance`), exactly."""
    poses = body_poses(arm.tree, [q[j] for j in range(q.shape[0])])
    caps = list(range(len(arm.cap_r)))
    a_w, b_w = capsule_endpoints(arm, poses, caps, q[0])
    a2 = tuple(x[:, None] for x in a_w)  # (nc, 1): capsules down, boxes across
    b2 = tuple(x[:, None] for x in b_w)
    center = tuple(centers[None, :, k] for k in range(3))
    rot = tuple(tuple(rots[None, :, r, c] for c in range(3)) for r in range(3))
    half = [halves[None, :, k] for k in range(3)]
    radius = np.asarray(arm.cap_r, np.float32)[:, None]
    d = capsule_box_clearance(a2, b2, radius, center, rot, half, unroll=unroll, cylinders=cylinders)  # type: ignore[arg-type]
    return BoxClearance(jnp.min(d, axis=0))


class BoxLowerBound(NamedTuple):
    box_bound: jnp.ndarray  # (nb,) [m]


def boxes_lower_bound(arm: ArmModel, q: jnp.ndarray, centers: jnp.ndarray, radii: jnp.ndarray) -> BoxLowerBound:
    """A lower bound of the arm's clearance at joint angles q (nj,) to each of nb boxes, from
    their centres (nb, 3) and circumradii (nb,) alone: each capsule axis's distance to the
    centre less the capsule's radius and the box's circumradius, the smallest over the
    capsules.  Far cheaper than `boxes_clearance`, which only the configurations this leaves
    in doubt need.  A padding box far away (radius 0) is harmless."""
    poses = body_poses(arm.tree, [q[j] for j in range(q.shape[0])])
    a_w, b_w = capsule_endpoints(arm, poses, list(range(len(arm.cap_r))), q[0])
    a = jnp.stack(a_w, axis=-1)[:, None]  # (nc, 1, 3)
    d = jnp.stack(b_w, axis=-1)[:, None] - a
    ap = centers[None] - a  # (nc, nb, 3)
    t = jnp.clip(jnp.sum(ap * d, axis=-1) / jnp.maximum(jnp.sum(d * d, axis=-1), 1e-12), 0.0, 1.0)
    off = ap - t[..., None] * d
    gap = jnp.sqrt(jnp.sum(off * off, axis=-1)) - np.asarray(arm.cap_r, np.float32)[:, None]
    return BoxLowerBound(jnp.min(gap, axis=0) - radii)


class CapsuleEnds(NamedTuple):
    """World endpoints of every capsule of the arm at one configuration."""

    a: jnp.ndarray  # (nc, 3)
    b: jnp.ndarray  # (nc, 3)


def capsule_ends(arm: ArmModel, q: jnp.ndarray) -> CapsuleEnds:
    """The capsules' world endpoints at joint angles q (nj,)."""
    poses = body_poses(arm.tree, [q[j] for j in range(q.shape[0])])
    a_w, b_w = capsule_endpoints(arm, poses, list(range(len(arm.cap_r))), q[0])
    return CapsuleEnds(jnp.stack(a_w, axis=-1), jnp.stack(b_w, axis=-1))
