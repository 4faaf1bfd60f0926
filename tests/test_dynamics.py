"""Inverse dynamics and friction against C MuJoCo's mj_inverse."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from conftest import random_configs

from kernels.dynamics import friction, inverse_dynamics_with_friction, rnea
from lmjx.edges.rollout_ref import gaz_friction

REL_TOL = 1e-4  # the acceptance bound, float32 kernels against float64 MuJoCo


def _contact_free_states(robot, n, seed):
    m = robot.mj
    d = mujoco.MjData(m)
    rng = np.random.default_rng(seed)
    q = random_configs(robot, 6 * n, seed)
    keep = []
    for i, qi in enumerate(q):
        d.qpos[:] = qi
        mujoco.mj_forward(m, d)
        if d.ncon == 0:
            keep.append(i)
        if len(keep) == n:
            break
    q = q[keep]
    qd = rng.uniform(-1, 1, q.shape) * robot.qd_max
    qdd = rng.uniform(-1, 1, q.shape) * robot.qdd_max
    return q, qd, qdd


def test_torques_match_mj_inverse_plus_friction(arm):
    robot = arm
    n = robot.nq
    q, qd, qdd = _contact_free_states(robot, 2000, seed=21)
    assert len(q) == 2000

    def one(a, b, c):
        return jnp.stack(
            inverse_dynamics_with_friction(
                robot.arm.tree,
                robot.inertials,
                robot.friction,
                [a[i] for i in range(n)],
                [b[i] for i in range(n)],
                [c[i] for i in range(n)],
            )
        )

    ours = np.asarray(jax.jit(jax.vmap(one))(*(jnp.asarray(x, jnp.float32) for x in (q, qd, qdd))))
    m = robot.mj
    d = mujoco.MjData(m)
    worst = 0.0
    for i in range(len(q)):
        d.qpos[:], d.qvel[:], d.qacc[:] = q[i], qd[i], qdd[i]
        mujoco.mj_inverse(m, d)
        ref = d.qfrc_inverse + gaz_friction(robot.friction, qd[i])
        worst = max(worst, np.linalg.norm(ours[i] - ref) / np.linalg.norm(ref))
    assert worst <= REL_TOL


def test_gravity_torques_at_rest(arm):
    """At rest, RNEA gives the gravity torques: mj_inverse with zero velocity and acceleration."""
    robot = arm
    q = random_configs(robot, 50, seed=3)
    m = robot.mj
    d = mujoco.MjData(m)
    for qi in q:
        tau = rnea(robot.arm.tree, robot.inertials, [float(x) for x in qi], [0.0] * robot.nq, [0.0] * robot.nq)
        d.qpos[:] = qi
        d.qvel[:] = 0
        d.qacc[:] = 0
        mujoco.mj_inverse(m, d)
        if d.ncon == 0:
            np.testing.assert_allclose(np.array(tau, float), d.qfrc_inverse, rtol=1e-9, atol=1e-9)


def test_friction_model():
    phi = np.array([[0.5, 1.0], [5.0, 10.0], [0.04, -0.02]])
    assert friction(phi, [0.0, 0.0]) == [0.0, 0.0]  # no friction at rest, by construction
    v = np.linspace(-2, 2, 41)
    f = np.array([friction(phi, [float(x), float(x)]) for x in v])
    assert np.all(np.diff(f, axis=0) > 0)  # increasing in velocity
    np.testing.assert_allclose(f, gaz_friction(phi, np.stack([v, v], axis=1)), rtol=1e-12, atol=1e-15)
    traced = np.asarray(jax.vmap(lambda x: jnp.stack(friction(phi, [x, x])))(jnp.asarray(v)))
    np.testing.assert_allclose(traced, f, atol=1e-6)
