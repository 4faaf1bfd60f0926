"""FK and Jacobians of the JAX kernels against C MuJoCo, pytorch_kinematics and finite differences."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from conftest import random_configs

from lmjx.kernels.kinematics import body_poses, body_poses_array, site_jacobian_array, site_positions_array

TOL = 1e-5  # metres (and unitless for rotations / Jacobians), float32 kernels


@pytest.fixture(scope="module")
def configs(robot):
    return random_configs(robot, 200, seed=11)


def _mujoco_fk(robot, q):
    m = robot.mj
    d = mujoco.MjData(m)
    xpos, xmat, spos = [], [], []
    for qi in q:
        d.qpos[:] = qi
        mujoco.mj_kinematics(m, d)
        xpos.append(d.xpos[1:].copy())
        xmat.append(d.xmat[1:].reshape(-1, 3, 3).copy())
        spos.append(d.site_xpos.copy())
    return np.array(xpos), np.array(xmat), np.array(spos)


def test_fk_matches_mujoco(robot, configs):
    fk = jax.jit(jax.vmap(lambda q: body_poses_array(robot.arm.tree, q)))
    sites = jax.jit(jax.vmap(lambda q: site_positions_array(robot.arm, q)))
    r, p = fk(jnp.asarray(configs, jnp.float32))
    s = sites(jnp.asarray(configs, jnp.float32))
    xpos, xmat, spos = _mujoco_fk(robot, configs)
    assert np.abs(np.asarray(p) - xpos).max() < TOL
    assert np.abs(np.asarray(r) - xmat).max() < TOL
    assert np.abs(np.asarray(s) - spos).max() < TOL


def test_jacobians_match_mujoco(robot, configs):
    m = robot.mj
    d = mujoco.MjData(m)
    names = ["tcp", "ip_hand", "ip_wrist", "ip_forearm", "ip_flange", "ip_elbow"]
    for name in names:
        sid = robot.site_index(name)
        jac = jax.jit(jax.vmap(lambda q, sid=sid: site_jacobian_array(robot.arm, q, sid)))
        jt, jr = jac(jnp.asarray(configs, jnp.float32))
        for i, q in enumerate(configs):
            d.qpos[:] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            jp = np.zeros((3, m.nv))
            jw = np.zeros((3, m.nv))
            mujoco.mj_jacSite(m, d, jp, jw, sid)
            assert np.abs(np.asarray(jt[i]) - jp).max() < TOL, name
            assert np.abs(np.asarray(jr[i]) - jw).max() < TOL, name


def test_fk_and_jacobian_match_pytorch_kinematics(robot, configs):
    torch = pytest.importorskip("torch")
    pytest.importorskip("pytorch_kinematics")
    from lmjx.baselines import pk_chain

    chain = pk_chain(robot, "tcp", dtype="float64")
    qt = torch.tensor(configs, dtype=torch.float64)
    m_pk = chain.forward_kinematics(qt).get_matrix().numpy()
    j_pk = chain.jacobian(qt).numpy()  # (n, 6, 7): linear then angular, world frame
    sid = robot.tcp_site
    s = jax.vmap(lambda q: site_positions_array(robot.arm, q))(jnp.asarray(configs, jnp.float32))
    jt, jr = jax.vmap(lambda q: site_jacobian_array(robot.arm, q, sid))(jnp.asarray(configs, jnp.float32))
    assert np.abs(np.asarray(s)[:, sid] - m_pk[:, :3, 3]).max() < TOL
    assert np.abs(np.asarray(jt) - j_pk[:, :3]).max() < TOL
    assert np.abs(np.asarray(jr) - j_pk[:, 3:]).max() < TOL


def test_jacobian_matches_finite_differences(robot, configs):
    """Central differences of the float32 FK; h = 1e-3 rad bounds the truncation error by
    ~|p|h^2/6 < 2e-7 and the round-off by ~1e-7/h = 1e-4."""
    sid = robot.site_index("ip_wrist")
    q = jnp.asarray(configs[:50], jnp.float32)
    jt, _ = jax.vmap(lambda x: site_jacobian_array(robot.arm, x, sid))(q)
    h = 1e-3
    pos = jax.vmap(lambda x: site_positions_array(robot.arm, x)[sid])
    for j in range(7):
        dq = jnp.zeros(7).at[j].set(h)
        fd = (pos(q + dq) - pos(q - dq)) / (2 * h)
        assert np.abs(np.asarray(fd) - np.asarray(jt[:, :, j])).max() < 2e-4


def test_locked_angles_as_constants_or_inputs_agree(robot, configs):
    """A locked joint folded in as a Python float gives the same FK as the traced angle."""
    tree = robot.arm.tree
    q = jnp.asarray(configs[:20], jnp.float32)

    def mixed(x):
        vals = [x[j] for j in range(5)] + [0.7, -0.7]
        return jnp.stack(
            [p.pos[2] if not isinstance(p.pos[2], float) else jnp.float32(p.pos[2]) for p in body_poses(tree, vals)]
        )

    def traced(x):
        x = x.at[5].set(0.7).at[6].set(-0.7)
        return body_poses_array(tree, x)[1][:, 2]

    assert np.abs(np.asarray(jax.vmap(mixed)(q)) - np.asarray(jax.vmap(traced)(q))).max() < 1e-6
