"""The Panda model against Franka's published kinematics, limits and PyBullet's meshes."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

READY = np.array([0, -np.pi / 4, 0, -3 * np.pi / 4, 0, np.pi / 2, np.pi / 4])

# Franka's published modified-DH parameters (a, d, alpha) of joints 1..7, then the flange.
DH = [
    (0, 0.333, 0),
    (0, 0, -np.pi / 2),
    (0, 0.316, np.pi / 2),
    (0.0825, 0, np.pi / 2),
    (-0.0825, 0.384, -np.pi / 2),
    (0, 0, np.pi / 2),
    (0.088, 0, np.pi / 2),
]
FLANGE_D = 0.107
EE_OFFSET = 0.1034  # F_T_EE: along the flange axis, rotated -pi/4 about it


def _mdh(a, d, alpha, theta):
    ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(theta), np.sin(theta)
    return np.array([[ct, -st, 0, a], [st * ca, ct * ca, -sa, -d * sa], [st * sa, ct * sa, ca, d * ca], [0, 0, 0, 1]])


def published_tcp(q):
    t = np.eye(4)
    for (a, d, al), th in zip(DH, q, strict=True):
        t = t @ _mdh(a, d, al, th)
    t = t @ _mdh(0, FLANGE_D, 0, 0)
    ee = _mdh(0, EE_OFFSET, 0, -np.pi / 4)
    return t, t @ ee


def _tcp(robot, q):
    m = robot.mj
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    s = robot.tcp_site
    return d.site_xpos[s].copy(), d.site_xmat[s].reshape(3, 3).copy()


@pytest.mark.parametrize("q", [np.zeros(7), READY], ids=["zero", "ready"])
def test_tcp_matches_published_kinematics(robot, q):
    _flange, ee = published_tcp(q)
    p, r = _tcp(robot, q)
    assert np.abs(p - ee[:3, 3]).max() < 1e-3  # the acceptance bound: 1 mm
    assert np.abs(p - ee[:3, 3]).max() < 1e-8  # in fact the same to round-off
    assert np.abs(r - ee[:3, :3]).max() < 1e-8


def test_panda_matches_its_dh_table_at_random_configurations(robot):
    """The flange and the TCP (position and orientation) equal Franka's modified-DH chain to
    1e-8 at 300 random configurations: every joint's axis and sign, not only at q = 0 and the
    ready pose (where J1, J3 and J5 are 0)."""
    from conftest import random_configs

    m, d = robot.mj, mujoco.MjData(robot.mj)
    for q in random_configs(robot, 300, seed=13):
        flange, ee = published_tcp(q)
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        for site, t in ((robot.flange_site, flange), (robot.tcp_site, ee)):
            assert np.abs(d.site_xpos[site] - t[:3, 3]).max() < 1e-8
            assert np.abs(d.site_xmat[site].reshape(3, 3) - t[:3, :3]).max() < 1e-8


def test_known_positions(robot):
    flange, _ = published_tcp(np.zeros(7))
    np.testing.assert_allclose(flange[:3, 3], [0.088, 0.0, 0.926], atol=1e-9)  # Franka: q = 0
    p, _ = _tcp(robot, READY)
    np.testing.assert_allclose(p, [0.30689, 0.0, 0.48688], atol=1e-4)


def test_limits_are_franka_datasheet(robot):
    np.testing.assert_allclose(robot.upper, [2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
    np.testing.assert_allclose(robot.lower, [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
    np.testing.assert_allclose(robot.qd_max, [2.175] * 4 + [2.61] * 3)
    np.testing.assert_allclose(robot.qdd_max, [15, 7.5, 10, 12.5, 15, 20, 20])
    np.testing.assert_allclose(robot.jerk_max, [7500, 3750, 5000, 6250, 7500, 10000, 10000])
    np.testing.assert_allclose(robot.tau_max, [87] * 4 + [12] * 3)
    np.testing.assert_allclose(robot.mj.jnt_actfrcrange[:, 1], robot.tau_max)
    np.testing.assert_allclose(robot.ready, READY, atol=1e-8)


def test_ready_pose_is_collision_free(robot):
    d = mujoco.MjData(robot.mj)
    d.qpos[:] = READY
    mujoco.mj_forward(robot.mj, d)
    assert d.ncon == 0


def test_interaction_points_and_hash(robot):
    for name in ("hand", "wrist", "forearm", "palm", "flange"):
        assert name in robot.interaction_points
    assert len(robot.model_hash) == 64
    assert robot.name == "lmjx_panda"


def _mesh_points(path, k=3000, seed=0):
    verts, faces = [], []
    with open(path) as fh:
        lines = fh.readlines()
    for line in lines:
        if line.startswith("v "):
            verts.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            idx = [int(t.split("/")[0]) - 1 for t in line.split()[1:]]
            faces += [[idx[0], idx[i], idx[i + 1]] for i in range(1, len(idx) - 1)]
    v, f = np.array(verts), np.array(faces)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    rng = np.random.default_rng(seed)
    i = rng.choice(len(f), k, p=area / area.sum())
    u = rng.random((k, 2))
    flip = u.sum(1) > 1
    u[flip] = 1 - u[flip]
    return np.vstack([a[i] + u[:, :1] * (b[i] - a[i]) + u[:, 1:] * (c[i] - a[i]), v])


@pytest.mark.parametrize(
    "link, body, max_out",
    [
        ("link0", "link0", 0.003),
        ("link1", "link1", 0.001),
        ("link2", "link2", 0.001),
        ("link3", "link3", 0.001),
        ("link4", "link4", 0.001),
        ("link5", "link5", 0.001),
        ("link6", "link6", 0.001),
        ("link7", "link7", 0.001),
        ("hand", "hand", 0.001),
        ("finger", "left_finger", 0.010),
    ],
)
def test_capsules_cover_pybullet_collision_meshes(robot, link, body, max_out):
    """Every link's capsules enclose PyBullet's Panda collision mesh of that link (the fingers,
    2 x 2.6 cm boxes approximated by one capsule, within 1 cm at their corners)."""
    pybullet_data = pytest.importorskip("pybullet_data")
    import os

    path = os.path.join(pybullet_data.getDataPath(), "franka_panda", "meshes", "collision", f"{link}.obj")
    pts = _mesh_points(path)
    arm = robot.arm
    b = robot.mj.body(body).id - 1
    caps = [c for c in range(len(arm.cap_r)) if arm.cap_body[c] == b]
    dist = np.full(len(pts), np.inf)
    for c in caps:
        a, e, r = arm.cap_a[c], arm.cap_b[c], arm.cap_r[c]
        ab = e - a
        t = np.clip((pts - a) @ ab / (ab @ ab), 0, 1)
        dist = np.minimum(dist, np.linalg.norm(pts - (a + t[:, None] * ab), axis=1) - r)
    assert dist.max() <= max_out
