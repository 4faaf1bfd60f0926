"""FK and Jacobians of the JAX kernels against C MuJoCo, pytorch_kinematics and finite
differences, for every shipped robot (`arm`); the UR5e's against UR's DH chain too."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from conftest import random_configs

from kernels.kinematics import body_poses, body_poses_array, site_jacobian_array, site_positions_array

TOL = 1e-5  # metres (and unitless for rotations / Jacobians), float32 kernels


@pytest.fixture(scope="module")
def configs(arm):
    return random_configs(arm, 200, seed=11)


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


def test_fk_matches_mujoco(arm, configs):
    fk = jax.jit(jax.vmap(lambda q: body_poses_array(arm.arm.tree, q)))
    sites = jax.jit(jax.vmap(lambda q: site_positions_array(arm.arm, q)))
    r, p = fk(jnp.asarray(configs, jnp.float32))
    s = sites(jnp.asarray(configs, jnp.float32))
    xpos, xmat, spos = _mujoco_fk(arm, configs)
    assert np.abs(np.asarray(p) - xpos).max() < TOL
    assert np.abs(np.asarray(r) - xmat).max() < TOL
    assert np.abs(np.asarray(s) - spos).max() < TOL


def test_jacobians_match_mujoco(arm, configs):
    m = arm.mj
    d = mujoco.MjData(m)
    names = ["tcp", "ip_hand", "ip_wrist", "ip_forearm", "ip_flange", "ip_elbow"]
    sids = [arm.site_index(name) for name in names]
    every = jax.jit(jax.vmap(lambda q: [site_jacobian_array(arm.arm, q, sid) for sid in sids]))  # one program
    for name, sid, (jt, jr) in zip(names, sids, every(jnp.asarray(configs, jnp.float32)), strict=True):
        for i, q in enumerate(configs):
            d.qpos[:] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            jp = np.zeros((3, m.nv))
            jw = np.zeros((3, m.nv))
            mujoco.mj_jacSite(m, d, jp, jw, sid)
            assert np.abs(np.asarray(jt[i]) - jp).max() < TOL, name
            assert np.abs(np.asarray(jr[i]) - jw).max() < TOL, name


def test_fk_and_jacobian_match_pytorch_kinematics(arm, configs):
    torch = pytest.importorskip("torch")
    pytest.importorskip("pytorch_kinematics")
    from lmjx.bench.baselines import pk_chain

    chain = pk_chain(arm, "tcp", dtype="float64")
    qt = torch.tensor(configs, dtype=torch.float64)
    m_pk = chain.forward_kinematics(qt).get_matrix().numpy()
    j_pk = chain.jacobian(qt).numpy()  # (n, 6, nq): linear then angular, world frame
    sid = arm.tcp_site
    s = jax.vmap(lambda q: site_positions_array(arm.arm, q))(jnp.asarray(configs, jnp.float32))
    jt, jr = jax.vmap(lambda q: site_jacobian_array(arm.arm, q, sid))(jnp.asarray(configs, jnp.float32))
    assert np.abs(np.asarray(s)[:, sid] - m_pk[:, :3, 3]).max() < TOL
    assert np.abs(np.asarray(jt) - j_pk[:, :3]).max() < TOL
    assert np.abs(np.asarray(jr) - j_pk[:, 3:]).max() < TOL


def test_jacobian_matches_finite_differences(arm, configs):
    """Central differences of the float32 FK; h = 1e-3 rad bounds the truncation error by
    ~|p|h^2/6 < 2e-7 and the round-off by ~1e-7/h = 1e-4."""
    sid = arm.site_index("ip_wrist")
    q = jnp.asarray(configs[:50], jnp.float32)
    jt, _ = jax.vmap(lambda x: site_jacobian_array(arm.arm, x, sid))(q)
    h = 1e-3
    pos = jax.vmap(lambda x: site_positions_array(arm.arm, x)[sid])
    for j in range(arm.nq):
        dq = jnp.zeros(arm.nq).at[j].set(h)
        fd = (pos(q + dq) - pos(q - dq)) / (2 * h)
        assert np.abs(np.asarray(fd) - np.asarray(jt[:, :, j])).max() < 2e-4


def test_locked_angles_as_constants_or_inputs_agree(arm, configs):
    """A locked joint folded in as a Python float gives the same FK as the traced angle."""
    tree = arm.arm.tree
    q = jnp.asarray(configs[:20], jnp.float32)
    n = arm.nq

    def mixed(x):
        vals = [x[j] for j in range(n - 2)] + [0.7, -0.7]
        return jnp.stack(
            [p.pos[2] if not isinstance(p.pos[2], float) else jnp.float32(p.pos[2]) for p in body_poses(tree, vals)]
        )

    def traced(x):
        x = x.at[n - 2].set(0.7).at[n - 1].set(-0.7)
        return body_poses_array(tree, x)[1][:, 2]

    assert np.abs(np.asarray(jax.vmap(mixed)(q)) - np.asarray(jax.vmap(traced)(q))).max() < 1e-6


# UR's published DH table of the UR5e ("DH Parameters for calculations of kinematics and
# dynamics"): the flange frame is A_1(q1) ... A_6(q6).
UR5E_D = (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996)
UR5E_A = (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0)
UR5E_ALPHA = (np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0)


def _ur5e_dh(q: np.ndarray) -> np.ndarray:
    t = np.eye(4)
    for qi, d, a, al in zip(q, UR5E_D, UR5E_A, UR5E_ALPHA, strict=True):
        ct, st, ca, sa = np.cos(qi), np.sin(qi), np.cos(al), np.sin(al)
        t = t @ np.array(
            [[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1]]
        )
    return t


def test_ur5e_flange_matches_ur_dh_table():
    """lmjx's UR5e: the flange (position to 1e-6 m, orientation to 1e-6) from C MuJoCo and
    from the float64 kernel equals UR's DH chain over random configurations."""
    from lmjx.model.robot import load_robot

    ur = load_robot("ur5e")
    q = random_configs(ur, 300, seed=5)
    m, d = ur.mj, mujoco.MjData(ur.mj)
    fl = ur.flange_site
    if hasattr(jax, "enable_x64"):
        x64 = jax.enable_x64
    else:  # older JAX
        from jax.experimental import enable_x64 as x64
    with x64(True):
        p_kernel = np.asarray(jax.vmap(lambda x: site_positions_array(ur.arm, x))(jnp.asarray(q, jnp.float64)))
    for i, qi in enumerate(q):
        t = _ur5e_dh(qi)
        d.qpos[:] = qi
        mujoco.mj_kinematics(m, d)
        assert np.abs(d.site_xpos[fl] - t[:3, 3]).max() < 1e-6
        assert np.abs(d.site_xmat[fl].reshape(3, 3) - t[:3, :3]).max() < 1e-6
        assert np.abs(p_kernel[i, fl] - t[:3, 3]).max() < 1e-6
