"""Damped least-squares inverse kinematics over the free joints of a (possibly failed) arm.

One problem: place a site (the TCP or another interaction point) on a target: a point
(x, y) on the table seen from above and a height band [z_lo, z_hi] (a point when
z_lo = z_hi).  A band lets a link touch an object at any height along it: a forearm can
reach a cube at a slant, not only lying flat at one height.  Two modes, chosen per problem by
a traced flag:

* PM (prehensile): the tool z axis must stay inside the cone from straight down to
  horizontal (its world z component <= 0); early iterations also pull it toward straight
  down with a weight that fades to zero halfway, so the final pose is set by the position
  task and the constraints alone;
* NPM (non-prehensile): position only, any orientation.

Inequalities (the tool cone; every capsule above the table) enter the damped least-squares
step as extra rows only while they are violated.  Locked joints are not variables at all:
the free joints are a static index list and the locked angles are constants folded into
the program.  The iteration count is fixed (no data-dependent exit) and joint limits are
enforced by projection after every step.  `ik_check` applies the acceptance tests.

Pure functions of one problem; batch with `jax.vmap`, jit at the entry point.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .collision import capsule_box_clearance, capsule_endpoints, self_clearance, table_clearance
from .kinematics import (
    body_poses,
    direction_jacobian,
    joint_frames,
    joint_values,
    point_in_world,
    point_jacobian,
    tool_axis,
)
from .linalg import cholesky_solve
from .math3 import Scalar, Vec, add, cvec, mul, neg, select, select_vec, sub, to_array, vcross, vsub
from .model import ArmModel


class IKSettings(NamedTuple):
    """Solver and acceptance parameters (static: they are compiled into the kernel)."""

    iterations: int = 64
    damping: float = 1e-3  # lambda^2 floor of the damped least squares
    damping_error: float = 0.05  # lambda^2 grows by this times the squared position error
    max_step: float = 0.3  # largest joint change per iteration [rad]
    down_weight: float = 0.3  # PM: weight of the pull toward a straight-down tool axis
    down_fraction: float = 0.5  # ... which fades to zero over this fraction of iterations
    cone_margin: float = 0.02  # PM: the solver aims for tool z <= -cone_margin
    table_margin: float = 0.004  # the solver keeps capsules this far above the table [m]
    pos_tol: float = 0.002  # accept: site within this distance of the target [m]
    accept_table: float = 0.001  # accept: every capsule at least this far from the table
    accept_self: float = 0.0  # accept: no capsule pair penetrates
    accept_cube: float = 0.0  # accept (PM): no capsule penetrates the grasped cube
    cube_half: float = 0.025  # half edge of the grasped cube [m]
    materialize: int = 1  # XLA hint: 0 none, 1 body poses, 2 + joint frames, 3 + normal equations
    unroll_checks: bool = False  # unroll the distance searches of the checks (fuses; larger code)


def _barrier(tree):
    """Materialize the traced leaves of `tree` (keeps XLA from recomputing them per fusion)."""
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    idx = [i for i, x in enumerate(leaves) if not isinstance(x, float)]
    vals = jax.lax.optimization_barrier([leaves[i] for i in idx])
    for i, v in zip(idx, vals, strict=True):
        leaves[i] = v
    return jax.tree_util.tree_unflatten(treedef, leaves)


def _table_groups(arm: ArmModel, free_idx: np.ndarray) -> list[list[int]]:
    """Table-checked capsules grouped by the set of free joints that move them.

    Capsules no free joint moves are left out: their height cannot change.
    """
    groups: dict[tuple[bool, ...], list[int]] = {}
    for c in arm.table_caps:
        key = tuple(bool(x) for x in arm.tree.ancestors[arm.cap_body[c]][free_idx])
        if any(key):
            groups.setdefault(key, []).append(int(c))
    return list(groups.values())


def ik_solve(
    arm: ArmModel,
    settings: IKSettings,
    free: tuple[int, ...],
    q_fixed: np.ndarray,
    sites: tuple[int, ...],
    target: jnp.ndarray,
    site: jnp.ndarray,
    pm: jnp.ndarray,
    q0_free: jnp.ndarray,
    free_mask: jnp.ndarray | None = None,
) -> jnp.ndarray:
    """Solve one IK problem.

    Args:
      arm: the robot.
      settings: solver parameters.
      free: indices of the free joints (static).
      q_fixed: (nj,) the angles of the locked joints (free entries are ignored): numpy to
        compile them in as constants, a JAX array to keep them as inputs.
      sites: the sites this batch may place (static); `site` indexes into it.
      target: (4,) x, y, z_lo, z_hi: the site must end at (x, y) with z_lo <= z <= z_hi.
      site: () int, which of `sites` to place.
      pm: () bool, prehensile mode (tool cone) or position only.
      q0_free: (nf,) initial free joint angles.
      free_mask: optional (nf,) 1.0 / 0.0 per free joint, traced: joints with 0 keep their
        initial angle (their Jacobian columns are zeroed, so the damped step leaves them
        exactly where they are).  With `free` = every joint this makes the set of locked
        joints an input: one program serves every failure (the failure atlas).
    Returns:
      (nf,) free joint angles after `settings.iterations` steps.
    """
    tree = arm.tree
    dtype = q0_free.dtype
    free_idx = np.asarray(free)
    nf = len(free)
    lower = [float(x) for x in arm.lower[free_idx]]
    upper = [float(x) for x in arm.upper[free_idx]]
    site_bodies = [int(arm.site_body[s]) for s in sites]
    pm_f = pm.astype(dtype)
    down_iters = max(1.0, settings.down_fraction * settings.iterations)
    tab_groups = _table_groups(arm, free_idx)

    def step(it: jnp.ndarray, qf: tuple[jnp.ndarray, ...]) -> tuple[jnp.ndarray, ...]:
        poses = body_poses(tree, joint_values(free, q_fixed, qf))
        if settings.materialize >= 1:
            poses = _barrier(poses)
        frames = joint_frames(tree, poses)
        if settings.materialize >= 2:
            frames = _barrier(frames)
        rows: list[tuple[list[Scalar], Scalar, Scalar]] = []  # (row over free joints, error, weight)

        # Position task (weight 1): the selected site onto the target.  The Jacobian columns
        # are computed once at the selected point and masked by whether the joint moves the
        # site's body.
        p_opts = [point_in_world(poses[b], cvec(arm.site_pos[s])) for s, b in zip(sites, site_bodies, strict=True)]
        p_site = select_vec(site, p_opts)
        z_goal = jnp.clip(p_site[2], target[2], target[3])
        e_pos = (target[0] - p_site[0], target[1] - p_site[1], z_goal - p_site[2])
        cols = []
        for j in free:
            mask = select(site, [float(tree.ancestors[b, j]) for b in site_bodies])
            c = vcross(frames[j].axis, vsub(p_site, frames[j].anchor))
            cols.append(tuple(mul(mask, x) for x in c))
        for k in range(3):
            rows.append(([col[k] for col in cols], e_pos[k], 1.0))

        # PM: the tool axis inside the cone (one row, only while violated) and, early on, a
        # fading pull toward straight down (three rows).
        z_tool = tool_axis(poses, arm.tool_body)
        dz = direction_jacobian(tree, frames, arm.tool_body, z_tool, free)  # d z_tool / dq
        tz = z_tool[2]
        w_cone = pm_f * (tz > -settings.cone_margin).astype(dtype)
        rows.append(([c[2] for c in dz], -settings.cone_margin - tz, w_cone))
        w_down = pm_f * settings.down_weight * jnp.maximum(0.0, 1.0 - it / down_iters)
        e_down = (neg(z_tool[0]), neg(z_tool[1]), sub(-1.0, z_tool[2]))
        for k in range(3):
            rows.append(([c[k] for c in dz], e_down[k], w_down))

        # Table: one row per group of capsules moved by the same free joints (their Jacobians
        # have the same columns), for the group's lowest point, while it is within
        # `table_margin` of the table top.
        for group in tab_groups:
            low: Vec | None = None
            low_clear: Scalar = 0.0
            for c in group:
                body = int(arm.cap_body[c])
                a = point_in_world(poses[body], cvec(arm.cap_a[c]))
                b = point_in_world(poses[body], cvec(arm.cap_b[c]))
                a_low = a[2] < b[2]
                p = tuple(jnp.where(a_low, a[k], b[k]) for k in range(3))
                clear = p[2] - float(arm.cap_r[c])
                if low is None:
                    low, low_clear = p, clear
                else:
                    lower_here = clear < low_clear
                    low = tuple(jnp.where(lower_here, p[k], low[k]) for k in range(3))
                    low_clear = jnp.minimum(clear, low_clear)
            clear = low_clear - arm.table_z
            cols = point_jacobian(tree, frames, int(arm.cap_body[group[0]]), low, free)
            w_tab = (clear < settings.table_margin).astype(dtype)
            rows.append(([col[2] for col in cols], settings.table_margin - clear, w_tab))

        if free_mask is not None:
            rows = [([mul(r, free_mask[i]) for i, r in enumerate(row)], err, w) for row, err, w in rows]

        # Damped normal equations over the free joints.
        lam = settings.damping + settings.damping_error * (e_pos[0] ** 2 + e_pos[1] ** 2 + e_pos[2] ** 2)
        h = [[0.0] * nf for _ in range(nf)]
        g: list[Scalar] = [0.0] * nf
        for row, err, w in rows:
            wr = [mul(w, r) for r in row]
            for i in range(nf):
                g[i] = add(g[i], mul(wr[i], err))
                for j in range(i + 1):
                    h[i][j] = add(h[i][j], mul(wr[i], row[j]))
        h[0][0] = add(h[0][0], lam)
        for i in range(1, nf):
            h[i][i] = add(h[i][i], lam)
        if settings.materialize >= 3:
            h, g = _barrier((h, g))
        dq = cholesky_solve(h, g)
        biggest = jnp.abs(dq[0])
        for d in dq[1:]:
            biggest = jnp.maximum(biggest, jnp.abs(d))
        scale = jnp.minimum(1.0, settings.max_step / (biggest + 1e-12))
        return tuple(jnp.clip(qf[k] + dq[k] * scale, lower[k], upper[k]) for k in range(nf))

    q0 = tuple(jnp.clip(q0_free[k], lower[k], upper[k]) for k in range(nf))
    return jnp.stack(jax.lax.fori_loop(0, settings.iterations, step, q0))


class IKCheck(NamedTuple):
    """Acceptance verdict and the measurements behind it, for one solution."""

    ok: jnp.ndarray  # () bool
    q: jnp.ndarray  # (nj,) full joint vector
    pos_err: jnp.ndarray  # () site-to-target distance (to the band) [m]
    tool_z: jnp.ndarray  # () world z component of the tool axis
    table: jnp.ndarray  # () smallest capsule clearance to the table [m]
    self: jnp.ndarray  # () smallest capsule-pair clearance [m]
    cube: jnp.ndarray  # () smallest clearance to the grasped cube (PM), +inf for NPM [m]


def grasp_cube_frame(poses, tool_body: int):
    """Orientation of an upright cube squared up with the gripper, as a scalar matrix.

    The cube stands on the table (its z axis vertical); its yaw follows the finger opening
    direction (the tool y axis) projected on the table, or the tool x axis turned by 90
    degrees when the opening direction is nearly vertical.
    """
    rot = poses[tool_body].rot
    yx, yy = rot[0][1], rot[1][1]
    xx, xy = rot[0][0], rot[1][0]
    use_y = yx * yx + yy * yy > 0.09
    vx = jnp.where(use_y, yx, xy)
    vy = jnp.where(use_y, yy, -xx)
    n = jnp.sqrt(jnp.maximum(vx * vx + vy * vy, 1e-12))
    vx, vy = vx / n, vy / n
    # columns: u = v x z, v, z
    return ((vy, vx, 0.0), (-vx, vy, 0.0), (0.0, 0.0, 1.0))


def ik_check(
    arm: ArmModel,
    settings: IKSettings,
    free: tuple[int, ...],
    q_fixed: np.ndarray,
    sites: tuple[int, ...],
    target: jnp.ndarray,
    site: jnp.ndarray,
    pm: jnp.ndarray,
    q_free: jnp.ndarray,
) -> IKCheck:
    """Accept or reject one IK result (arguments as for `ik_solve`).

    Accepted means: the site is within `pos_tol` of the target (the point (x, y) at a
    height inside the band); joint limits hold; every
    capsule is at least `accept_table` from the table; no checked capsule pair penetrates;
    and for PM the tool axis points at or below horizontal and no capsule penetrates an
    upright cube of edge 2 * `cube_half`, centred on the target (x, y, z_lo) and squared up with the
    fingers.
    """
    tree = arm.tree
    dtype = q_free.dtype
    qv = joint_values(free, q_fixed, q_free)
    poses = body_poses(tree, qv)
    like = q_free[0]
    p_site = select_vec(site, [point_in_world(poses[int(arm.site_body[s])], cvec(arm.site_pos[s])) for s in sites])
    dz = p_site[2] - jnp.clip(p_site[2], target[2], target[3])
    pos_err = jnp.sqrt((p_site[0] - target[0]) ** 2 + (p_site[1] - target[1]) ** 2 + dz * dz)
    tool_z = to_array(tool_axis(poses, arm.tool_body)[2], like)
    all_caps = list(range(len(arm.cap_r)))
    a_w, b_w = capsule_endpoints(arm, poses, all_caps, like)
    tab = np.asarray(arm.table_caps)
    table = jnp.min(
        table_clearance(arm, tuple(x[tab] for x in a_w), tuple(x[tab] for x in b_w), settings.unroll_checks),
        initial=jnp.inf,
    )
    selfc = jnp.min(self_clearance(arm, a_w, b_w)) if len(arm.self_pairs) else jnp.asarray(jnp.inf, dtype)
    cube_all = capsule_box_clearance(
        a_w,
        b_w,
        np.asarray(arm.cap_r, np.float32),
        (target[0], target[1], target[2]),
        grasp_cube_frame(poses, arm.tool_body),
        [settings.cube_half] * 3,
        unroll=settings.unroll_checks,
    )
    cube = jnp.where(pm, jnp.min(cube_all), jnp.inf)
    q = jnp.stack([to_array(x, like) for x in qv])
    in_limits = jnp.all(q >= arm.lower - 1e-6) & jnp.all(q <= arm.upper + 1e-6)
    ok = (
        (pos_err <= settings.pos_tol)
        & in_limits
        & (table >= settings.accept_table)
        & (selfc >= settings.accept_self)
        & jnp.logical_or(~pm, (tool_z <= 0.0) & (cube >= settings.accept_cube))
    )
    return IKCheck(ok, q, pos_err, tool_z, table, selfc, cube)
