"""Collision kernels against C MuJoCo: contact verdicts and distances."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from conftest import random_configs

from kernels.collision import (
    capsule_box_clearance,
    capsule_endpoints,
    segment_distance,
    self_clearance,
    table_clearance,
)
from kernels.kinematics import body_poses
from kernels.math3 import cmat, cvec


def _clearances(robot, q):
    arm = robot.arm
    caps = list(range(len(arm.cap_r)))

    def one(x):
        poses = body_poses(arm.tree, [x[j] for j in range(7)])
        a, b = capsule_endpoints(arm, poses, caps, x[0])
        tab = np.asarray(arm.table_caps)
        return (
            self_clearance(arm, a, b),
            table_clearance(arm, tuple(v[tab] for v in a), tuple(v[tab] for v in b)),
        )

    s, t = jax.jit(jax.vmap(one))(jnp.asarray(q, jnp.float32))
    return np.asarray(s), np.asarray(t)


def test_verdicts_agree_with_mujoco_contacts(robot):
    """On 10,000 random configurations, our 'penetrating' verdict for every checked capsule
    pair and every capsule-table pair equals the presence of a C MuJoCo contact between those
    geoms, except where the clearance is within 1e-4 m of zero (the stated margin)."""
    m = robot.mj
    d = mujoco.MjData(m)
    arm = robot.arm
    q = random_configs(robot, 10_000, seed=5)
    selfc, tablec = _clearances(robot, q)
    geom_of_cap = [g for g in range(m.ngeom) if m.geom_bodyid[g] != 0]
    pair_index = {(geom_of_cap[i], geom_of_cap[j]): k for k, (i, j) in enumerate(arm.self_pairs)}
    table_index = {geom_of_cap[c]: k for k, c in enumerate(arm.table_caps)}
    table_id = m.geom("table").id
    mj_self = np.zeros(selfc.shape, bool)
    mj_table = np.zeros(tablec.shape, bool)
    for n, qi in enumerate(q):
        d.qpos[:] = qi
        mujoco.mj_forward(m, d)
        for c in d.contact[: d.ncon]:
            g1, g2 = sorted((int(c.geom1), int(c.geom2)))
            if g1 == table_id:
                mj_table[n, table_index[g2]] = True  # KeyError: a contact we do not check
            else:
                mj_self[n, pair_index[(g1, g2)]] = True
    margin = 1e-4
    for ours, theirs in ((selfc, mj_self), (tablec, mj_table)):
        differ = ((ours < 0) != theirs) & (np.abs(ours) > margin)
        assert not differ.any(), f"{differ.sum()} disagreements"
    assert selfc.size + tablec.size > 2_000_000
    assert mj_self.sum() > 1000 and mj_table.sum() > 1000  # both kinds of contact do occur


def test_distances_match_mj_geom_distance(robot):
    """Separation distances agree with mj_geomDistance to 2e-5 m; for penetrating pairs only
    the sign is compared (penetration depth has no single definition)."""
    m = robot.mj
    d = mujoco.MjData(m)
    arm = robot.arm
    q = random_configs(robot, 60, seed=9)
    selfc, tablec = _clearances(robot, q)
    geom_of_cap = [g for g in range(m.ngeom) if m.geom_bodyid[g] != 0]
    table_id = m.geom("table").id
    fromto = np.zeros(6)
    worst = 0.0
    for n, qi in enumerate(q):
        d.qpos[:] = qi
        mujoco.mj_forward(m, d)
        for k, (i, j) in enumerate(arm.self_pairs[::7]):
            ref = mujoco.mj_geomDistance(m, d, geom_of_cap[i], geom_of_cap[j], 10.0, fromto)
            worst = max(worst, _compare(ref, selfc[n, k * 7]))
        for k, c in enumerate(arm.table_caps):
            ref = mujoco.mj_geomDistance(m, d, geom_of_cap[c], table_id, 10.0, fromto)
            worst = max(worst, _compare(ref, tablec[n, k]))
    assert worst < 2e-5


def _compare(ref: float, ours: float) -> float:
    if ref > 0 or ours > 0:
        return abs(ref - ours)
    return 0.0  # both penetrating


BOX_XML = """
<mujoco>
  <worldbody>
    <body name="cap" mocap="true"><geom name="cap" type="capsule" fromto="0 0 -0.07 0 0 0.07" size="0.03"/></body>
    <body name="box" mocap="true"><geom name="box" type="box" size="0.025 0.04 0.02"/></body>
  </worldbody>
</mujoco>
"""


def test_capsule_box_distance_matches_mujoco():
    m = mujoco.MjModel.from_xml_string(BOX_XML)
    d = mujoco.MjData(m)
    rng = np.random.default_rng(3)
    n = 500
    pos_c = rng.uniform(-0.15, 0.15, (n, 3))
    pos_b = rng.uniform(-0.05, 0.05, (n, 3))
    quat_c = rng.normal(size=(n, 4))
    quat_c /= np.linalg.norm(quat_c, axis=1, keepdims=True)
    yaw = rng.uniform(-np.pi, np.pi, n)
    ref = np.zeros(n)
    a_w, b_w, rot_b = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3, 3))
    fromto = np.zeros(6)
    for i in range(n):
        d.mocap_pos[0], d.mocap_quat[0] = pos_c[i], quat_c[i]
        d.mocap_pos[1], d.mocap_quat[1] = pos_b[i], [np.cos(yaw[i] / 2), 0, 0, np.sin(yaw[i] / 2)]
        mujoco.mj_forward(m, d)
        ref[i] = mujoco.mj_geomDistance(m, d, 0, 1, 10.0, fromto)
        axis = d.geom_xmat[0].reshape(3, 3)[:, 2]
        a_w[i], b_w[i] = d.geom_xpos[0] - 0.07 * axis, d.geom_xpos[0] + 0.07 * axis
        rot_b[i] = d.geom_xmat[1].reshape(3, 3)

    def one(a, b, c, r):
        rot = tuple(tuple(r[i, j] for j in range(3)) for i in range(3))
        return capsule_box_clearance(
            tuple(a[k][None] for k in range(3)),
            tuple(b[k][None] for k in range(3)),
            0.03,
            (c[0], c[1], c[2]),
            rot,
            [0.025, 0.04, 0.02],
        )[0]

    ours = np.asarray(jax.vmap(one)(jnp.asarray(a_w), jnp.asarray(b_w), jnp.asarray(pos_b), jnp.asarray(rot_b)))
    apart = (ref > 0) | (ours > 0)
    assert apart.sum() > 200
    assert np.abs(ours - ref)[apart].max() < 2e-5
    assert np.array_equal(ours < 0, ref < 0)


def test_segment_distance_against_dense_sampling():
    rng = np.random.default_rng(0)
    p1, q1, p2, q2 = (rng.uniform(-1, 1, (300, 3)) for _ in range(4))
    q2[:20] = p2[:20] + 1e-9  # degenerate segments
    q1[20:40] = p1[20:40] + 0.3 * (q2[20:40] - p2[20:40])  # parallel pairs
    ours = np.asarray(
        segment_distance(
            tuple(jnp.asarray(p1[:, k]) for k in range(3)),
            tuple(jnp.asarray(q1[:, k]) for k in range(3)),
            tuple(jnp.asarray(p2[:, k]) for k in range(3)),
            tuple(jnp.asarray(q2[:, k]) for k in range(3)),
        )
    )
    # the reference: 1001 points along the first segment, each at its exact (closed-form)
    # distance to the second; its minimum exceeds the true distance by at most the spacing
    t = np.linspace(0, 1, 1001)
    for i in range(300):
        a = p1[i] + t[:, None] * (q1[i] - p1[i])
        ab = q2[i] - p2[i]
        u = np.clip((a - p2[i]) @ ab / max(ab @ ab, 1e-300), 0, 1)
        brute = np.min(np.linalg.norm(a - (p2[i] + u[:, None] * ab), axis=-1))
        assert ours[i] <= brute + 1e-6
        assert brute - ours[i] < 3e-3  # the grid's resolution bounds the brute-force excess


def test_constant_helpers_fold():
    assert cvec(np.array([1e-12, 1.0 - 1e-12, -2.0])) == (0.0, 1.0, -2.0)
    assert cmat(np.eye(3)) == ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


@pytest.mark.parametrize("n", [1, 4])
def test_capsule_box_inside_is_negative(n):
    """A capsule through a box's centre has negative clearance of about -(half + r)."""
    a = tuple(jnp.full((n,), v) for v in (-0.01, 0.0, 0.0))
    b = tuple(jnp.full((n,), v) for v in (0.01, 0.0, 0.0))
    eye = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    c = capsule_box_clearance(a, b, 0.01, (0.0, 0.0, 0.0), eye, [0.05, 0.05, 0.05])
    np.testing.assert_allclose(np.asarray(c), -0.06, atol=1e-6)


@pytest.mark.parametrize("number", [2, 3])
def test_scene_box_clearance_matches_mj_geom_distance(robot, number):
    """The transits' box-clearance kernel (the planner's program: the scene's boxes as
    inputs) against C MuJoCo's mj_geomDistance between every arm capsule and every box of a
    scenario's scene (scenario 3: twelve movable boxes, turned; scenario 2: the tunnel's fixed
    walls and roof), at random configurations: the smallest over the capsules per box."""
    from lmjx.model.failure import parse_failure
    from lmjx.planner.transit import TransitPlanner
    from lmjx.sim.scenarios import sample_layout, scenario
    from lmjx.sim.scene import build_scene, object_qpos, read_objects, set_state

    sc = scenario(number, tasks="hard")
    scene = build_scene(robot, sc)
    m, d = scene.model, mujoco.MjData(scene.model)
    q = random_configs(robot, 2000, 11)
    set_state(scene, d, q[0], object_qpos(scene, sample_layout(sc, 4).poses))
    mujoco.mj_kinematics(m, d)
    objects = read_objects(scene, d)
    transits = TransitPlanner(robot, parse_failure("none", robot), batched=True)
    transits.set_scene(sc, objects)
    # the 100 configurations nearest the boxes (by the kernel) and 20 others
    near = np.argsort(transits.box_clearance(q).min(axis=1))
    q = q[np.concatenate([near[:100], near[-20:]])]
    ours = transits.box_clearance(q)
    robot_bodies = {robot.mj.body(b).name for b in range(1, robot.mj.nbody)}
    arm_geoms = [g for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE
                 and m.body(int(m.geom_bodyid[g])).name in robot_bodies and m.geom_contype[g]]  # fmt: skip
    box_geoms = [m.geom(f"{b.name}_geom").id for b in sc.movable] + [m.geom(b.name).id for b in sc.fixed]
    assert len(arm_geoms) == len(robot.arm.cap_r) and ours.shape == (len(q), len(box_geoms))
    ref = np.zeros_like(ours, np.float64)
    fromto = np.zeros(6)
    for i, x in enumerate(q):
        d.qpos[scene.robot_qpos] = x
        mujoco.mj_kinematics(m, d)
        for k, g in enumerate(box_geoms):
            ref[i, k] = min(mujoco.mj_geomDistance(m, d, a, g, 10.0, fromto) for a in arm_geoms)
    apart = (ref > 0) | (ours > 0)
    assert apart.sum() > 0.5 * ref.size and (ref < 0.02).sum() > 20 and (ref < 0).sum() > 0
    assert np.abs(ours - ref)[apart].max() < 5e-5
    assert np.array_equal(ours < 0, ref < 0)


def test_box_lower_bound_against_numpy_and_the_exact_clearance(robot):
    """The planner's lower bound of the clearance to boxes (`boxes_lower_bound`: capsule axis
    to box centre, less the capsule's radius and the box's circumradius) against the same
    bound in float64 numpy from the capsules' ends, and never above the exact clearance
    (`boxes_clearance`) at random configurations of scenario 3's twelve boxes."""
    from lmjx.edges.index import capsule_ends_kernel
    from lmjx.model.failure import parse_failure
    from lmjx.planner.transit import TransitPlanner
    from lmjx.sim.scenarios import sample_layout, scenario
    from lmjx.sim.scene import build_scene, object_qpos
    from lmjx.sim.sceneboxes import BOUND_SLACK

    sc = scenario(3, tasks="hard")
    objects = object_qpos(build_scene(robot, sc), sample_layout(sc, 4).poses)
    transits = TransitPlanner(robot, parse_failure("none", robot), batched=True)
    transits.set_scene(sc, objects)
    q = random_configs(robot, 1500, 12)
    ours = transits.lower_bounds(q)
    ends = capsule_ends_kernel(robot).run(q.astype(np.float32))
    a, b = ends["a"].astype(np.float64), ends["b"].astype(np.float64)
    ap = transits.scene.centers[None, None] - a[:, :, None]  # (n, nc, nb, 3)
    d = (b - a)[:, :, None]
    t = np.clip(np.sum(ap * d, -1) / np.maximum(np.sum(d * d, -1), 1e-12), 0, 1)
    gap = np.linalg.norm(ap - t[..., None] * d, axis=-1) - np.asarray(robot.arm.cap_r)[None, :, None]
    ref = gap.min(axis=1) - np.linalg.norm(transits.scene.halves, axis=1)[None]
    assert np.abs(ours + BOUND_SLACK - ref).max() < 5e-6
    exact = transits.box_clearance(q)
    assert (ours <= exact).all() and (exact - ours).min() < 0.01  # a bound, tight where a capsule end nears a box
