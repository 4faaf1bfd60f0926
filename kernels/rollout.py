"""Edge rollouts (paper Algorithm 2): a constant Cartesian twist command for one point on the
arm, followed for a fixed duration with the arm's dynamics, limits and collisions checked at
every control step.

Per state k = 0 .. L (L control steps of dt):
    qd_k  = J^+ v                 velocity of the free joints that best produces the twist v
    qdd_k = J^+ (a - Jdot qd_k)   with a = 0: the twist stays constant
    tau_k = M qdd + C qd + g + f(qd)   (recursive Newton-Euler + Gaz et al. friction)
    m_k   = sqrt(det(J J^T))      manipulability (sqrt(det(J^T J)) when fewer than 6 joints move)
    reject the edge if q_k leaves the position limits, |qd|, |qdd| or |tau| exceed their
    limits (free joints), or a capsule pair or the table is penetrated;
    q_{k+1} = q_k + qd_k dt.
J is the 6 x n_free Jacobian (linear velocity of the point, angular velocity of its body);
J^+ is the damped least-squares inverse (J^T (J J^T + lambda I)^-1 for a redundant arm,
(J^T J + lambda I)^-1 J^T when fewer than 6 joints move), and Jdot qd is exact
(forward-mode derivative of J along qd).  Shapes are fixed (`steps + 1` state rows per
edge); the loop over states stops at the edge's length or first violation.  Pure functions of one edge; batch with
`jax.vmap`, jit at the entry point.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .collision import capsule_endpoints, self_clearance, table_clearance
from .dynamics import Inertials, inverse_dynamics_with_friction
from .kinematics import body_poses, joint_frames, joint_values, point_in_world
from .linalg import cholesky_solve, cholesky_sqrt_det
from .math3 import Scalar, cvec, mul, select, select_vec, to_array, vcross, vsub
from .model import ArmModel

REASONS = ("ok", "position", "velocity", "acceleration", "torque", "self_collision", "table_collision")


class Limits(NamedTuple):
    """Joint limits and friction, all joints.  The limits are numpy arrays (folded into the
    program as constants) or JAX arrays (inputs: one program for any limits); the friction
    parameters are numpy constants."""

    qd_max: np.ndarray | jnp.ndarray  # (nj,) [rad/s]
    qdd_max: np.ndarray | jnp.ndarray  # (nj,) [rad/s^2]
    tau_max: np.ndarray | jnp.ndarray  # (nj,) [Nm]
    friction: np.ndarray  # (3, nj) Gaz et al. phi1, phi2, phi3


class RolloutSettings(NamedTuple):
    """Static rollout parameters."""

    dt: float = 0.02  # control period [s]
    steps: int = 100  # longest edge, in control steps
    damping: float = 1e-6  # lambda of the damped least-squares inverse J^+
    self_margin: float = 0.0  # reject when a capsule pair is closer than this [m]
    table_margin: float = 0.0  # reject when a capsule is closer to the table than this [m]
    unroll_checks: bool = False  # unroll the table-distance search (fuses on GPUs)


class EdgeResult(NamedTuple):
    """One rollout.  Per-state arrays have steps + 1 rows; rows past the edge's length or
    after its first violation are not part of the edge."""

    q: jnp.ndarray  # (steps + 1, nf) free joint angles
    qd: jnp.ndarray  # (steps + 1, nf) free joint velocities
    p: jnp.ndarray  # (steps + 1, 3) world position of the point
    valid: jnp.ndarray  # () bool: no violation in states 0 .. length
    fail_step: jnp.ndarray  # () int32: first violating state, -1 if none
    reason: jnp.ndarray  # () int32: index into REASONS of the first violation (0: none)
    min_manipulability: jnp.ndarray  # () over states 0 .. length
    peak_torque_ratio: jnp.ndarray  # () max |tau_i| / tau_max_i over free joints and states
    peak_velocity_ratio: jnp.ndarray  # ()
    peak_acceleration_ratio: jnp.ndarray  # ()


def _jacobian(arm: ArmModel, free: tuple[int, ...], q_fixed, sites: tuple[int, ...], site, qf: jnp.ndarray):
    """(6, nf) Jacobian of the selected site (linear rows, then angular rows of its body)."""
    tree = arm.tree
    poses = body_poses(tree, joint_values(free, q_fixed, qf))
    frames = joint_frames(tree, poses)
    bodies = [int(arm.site_body[s]) for s in sites]
    p = select_vec(site, [point_in_world(poses[b], cvec(arm.site_pos[s])) for s, b in zip(sites, bodies, strict=True)])
    cols = []
    for j in free:
        mask = select(site, [float(tree.ancestors[b, j]) for b in bodies])
        lin = vcross(frames[j].axis, vsub(p, frames[j].anchor))
        cols.append([mul(mask, x) for x in lin] + [mul(mask, x) for x in frames[j].axis])
    like = qf[0]
    return jnp.stack([jnp.stack([to_array(cols[c][r], like) for c in range(len(free))]) for r in range(6)])


def _lstsq(jac: jnp.ndarray, b: list[Scalar], damping: float) -> list[Scalar]:
    """Damped least-squares J^+ b for J (6, nf): J^T (J J^T + damping I)^-1 b when the arm is
    redundant (nf >= 6: the minimum-norm solution, well conditioned away from singularities),
    (J^T J + damping I)^-1 J^T b otherwise (the least-squares solution).  Both are J^+ b as
    the damping goes to zero."""
    nf = jac.shape[1]
    if nf >= 6:
        h = [[sum(jac[i, c] * jac[j, c] for c in range(nf)) for j in range(i + 1)] for i in range(6)]
        for i in range(6):
            h[i][i] = h[i][i] + damping
        y = cholesky_solve(h, b)
        return [sum(jac[r, c] * y[r] for r in range(6)) for c in range(nf)]
    h = [[sum(jac[r, i] * jac[r, j] for r in range(6)) for j in range(i + 1)] for i in range(nf)]
    for i in range(nf):
        h[i][i] = h[i][i] + damping
    g = [sum(jac[r, i] * b[r] for r in range(6)) for i in range(nf)]
    return cholesky_solve(h, g)


def _manipulability(jac: jnp.ndarray) -> Scalar:
    nf = jac.shape[1]
    if nf >= 6:
        a = [[sum(jac[i, c] * jac[j, c] for c in range(nf)) for j in range(i + 1)] for i in range(6)]
    else:
        a = [[sum(jac[r, i] * jac[r, j] for r in range(6)) for j in range(i + 1)] for i in range(nf)]
    return cholesky_sqrt_det(a)


def _per_joint(x, idx: np.ndarray) -> list:
    """The entries `idx` of a limit: Python floats from numpy (constants), scalars of a JAX array (inputs)."""
    if isinstance(x, np.ndarray):
        return [float(v) for v in x[idx]]
    return [x[int(j)] for j in idx]


def edge_rollout(
    arm: ArmModel,
    inertials: Inertials,
    limits: Limits,
    settings: RolloutSettings,
    free: tuple[int, ...],
    q_fixed,
    sites: tuple[int, ...],
    site: jnp.ndarray,
    q0_free: jnp.ndarray,
    twist: jnp.ndarray,
    length: jnp.ndarray,
) -> EdgeResult:
    """Roll out one edge.

    Args:
      arm, inertials, limits: the robot (`Limits`: constants or inputs).
      settings: static rollout parameters.
      free: indices of the free joints (static); q_fixed: (nj,) locked angles (numpy: folded
        in as constants; a JAX array: inputs).
      sites: candidate points (static); site: () int index into `sites`.
      q0_free: (nf,) start configuration of the free joints.
      twist: (6,) commanded linear [m/s] and angular [rad/s] velocity of the point.
      length: () int, number of control steps L (1 .. steps).
    """
    tree = arm.tree
    nf = len(free)
    free_idx = np.asarray(free)
    lo = [float(x) for x in arm.lower[free_idx]]
    hi = [float(x) for x in arm.upper[free_idx]]
    qd_max, qdd_max, tau_max = (_per_joint(x, free_idx) for x in (limits.qd_max, limits.qdd_max, limits.tau_max))
    bodies = [int(arm.site_body[s]) for s in sites]
    all_caps = list(range(len(arm.cap_r)))
    tab = np.asarray(arm.table_caps)
    v = [twist[i] for i in range(6)]
    dtype = q0_free.dtype

    def jac_of(qf: jnp.ndarray) -> jnp.ndarray:
        return _jacobian(arm, free, q_fixed, sites, site, qf)

    def state(carry: tuple, k: jnp.ndarray) -> tuple[tuple, tuple]:
        qf, alive, fail_step, reason, m_min, tau_pk, qd_pk, qdd_pk = carry
        jac, jac_dot_along = jax.linearize(jac_of, qf)
        qd = _lstsq(jac, v, settings.damping)
        qd_arr = jnp.stack(qd)
        jdot = jac_dot_along(qd_arr)  # dJ/dt at velocity qd
        bias = [-sum(jdot[r, c] * qd[c] for c in range(nf)) for r in range(6)]
        qdd = _lstsq(jac, bias, settings.damping)

        q_list = joint_values(free, q_fixed, [qf[c] for c in range(nf)])
        pos = {j: c for c, j in enumerate(free)}
        qd_full = [qd[pos[j]] if j in pos else 0.0 for j in range(len(q_list))]
        qdd_full = [qdd[pos[j]] if j in pos else 0.0 for j in range(len(q_list))]
        poses = body_poses(tree, q_list)
        tau = inverse_dynamics_with_friction(tree, inertials, limits.friction, q_list, qd_full, qdd_full, poses)
        tau_free = [tau[j] for j in free]

        a_w, b_w = capsule_endpoints(arm, poses, all_caps, qf[0])
        self_c = jnp.min(self_clearance(arm, a_w, b_w)) if len(arm.self_pairs) else jnp.asarray(jnp.inf, dtype)
        table_c = jnp.min(
            table_clearance(arm, tuple(x[tab] for x in a_w), tuple(x[tab] for x in b_w), settings.unroll_checks),
            initial=jnp.inf,
        )
        p = select_vec(
            site, [point_in_world(poses[b], cvec(arm.site_pos[s])) for s, b in zip(sites, bodies, strict=True)]
        )

        pos_ok = jnp.all(jnp.stack([(qf[c] >= lo[c] - 1e-6) & (qf[c] <= hi[c] + 1e-6) for c in range(nf)]))
        qd_ratio = jnp.max(jnp.stack([jnp.abs(qd[c]) / qd_max[c] for c in range(nf)]))
        qdd_ratio = jnp.max(jnp.stack([jnp.abs(qdd[c]) / qdd_max[c] for c in range(nf)]))
        tau_ratio = jnp.max(jnp.stack([jnp.abs(tau_free[c]) / tau_max[c] for c in range(nf)]))
        fails = [~pos_ok, qd_ratio > 1.0, qdd_ratio > 1.0, tau_ratio > 1.0, self_c < settings.self_margin,
                 table_c < settings.table_margin]  # fmt: skip
        reason_k = jnp.int32(0)
        for code in range(len(fails), 0, -1):  # the first failing check in REASONS order wins
            reason_k = jnp.where(fails[code - 1], jnp.int32(code), reason_k)

        active = alive & (k <= length)
        fail_now = active & (reason_k > 0)
        ok_now = active & (reason_k == 0)
        new_carry = (
            jnp.where(k < length, qf + qd_arr * settings.dt, qf),
            alive & ~fail_now,
            jnp.where(fail_now, k, fail_step),
            jnp.where(fail_now, reason_k, reason),
            jnp.where(ok_now, jnp.minimum(m_min, _manipulability(jac)), m_min),
            jnp.where(ok_now, jnp.maximum(tau_pk, tau_ratio), tau_pk),
            jnp.where(ok_now, jnp.maximum(qd_pk, qd_ratio), qd_pk),
            jnp.where(ok_now, jnp.maximum(qdd_pk, qdd_ratio), qdd_pk),
        )
        return new_carry, (qf, qd_arr, jnp.stack([to_array(x, qf[0]) for x in p]))

    # A while loop rather than a scan: it stops once the edge has failed or ended, so a
    # batch of edges stops with its longest live edge (lmjx sorts edges by length).
    n_states = settings.steps + 1

    def cond(loop: tuple) -> jnp.ndarray:
        k, carry, _ = loop
        return (k < n_states) & carry[1] & (k <= length)

    def body(loop: tuple) -> tuple:
        k, carry, (qs, qds, ps) = loop
        carry, (qf, qd, p) = state(carry, k)
        return k + 1, carry, (qs.at[k].set(qf), qds.at[k].set(qd), ps.at[k].set(p))

    zero = jnp.zeros((), dtype)
    init = (q0_free, jnp.asarray(True), jnp.int32(-1), jnp.int32(0), zero + jnp.inf, zero, zero, zero)
    outs = (
        jnp.zeros((n_states, nf), dtype),
        jnp.zeros((n_states, nf), dtype),
        jnp.zeros((n_states, 3), dtype),
    )
    _, carry, (qs, qds, ps) = jax.lax.while_loop(cond, body, (jnp.int32(0), init, outs))
    _, alive, fail_step, reason, m_min, tau_pk, qd_pk, qdd_pk = carry
    return EdgeResult(qs, qds, ps, alive, fail_step, reason, m_min, tau_pk, qd_pk, qdd_pk)
