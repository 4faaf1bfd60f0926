"""`lmjx robot import` against independent references: the source URDF's forward kinematics
(pytorch_kinematics), the source's collision meshes posed by C MuJoCo (every vertex inside a
capsule of the imported arm at the same configuration), brute-force geometry for the fit,
and one-line refusals of bad sources."""

from __future__ import annotations

import itertools
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pytest

from lmjx.model.capsule_fit import capsule_along, coverage, enclosing_circle, fit_capsules, union_volume
from lmjx.model.import_source import SourceError, arm_chain, load_source
from lmjx.model.robot import check_robot
from lmjx.model.robot_import import ImportOptions, import_robot

pybullet_data = pytest.importorskip("pybullet_data")
DATA = Path(pybullet_data.getDataPath())
ARMS = {
    "iiwa": ("kuka_iiwa/model.urdf", ImportOptions(qdd_max="15"), "lbr_iiwa_link_7"),
    "xarm6": ("xarm/xarm6_robot.urdf", ImportOptions(qdd_max="15"), "link6"),
    "panda": (
        "franka_panda/panda.urdf",
        ImportOptions(qdd_max="15,7.5,10,12.5,15,20,20", tcp="panda_hand:0,0,0.1034", flange="panda_link8"),
        "panda_link8",
    ),
}


@pytest.fixture(scope="module")
def imported(tmp_path_factory) -> dict[str, tuple[Path, object]]:
    out = {}
    d = tmp_path_factory.mktemp("arms")
    for k, (rel, opt, _) in ARMS.items():
        out[k] = (d / f"{k}.xml", import_robot(DATA / rel, d / f"{k}.xml", opt))
    return out


@pytest.mark.parametrize("arm", list(ARMS))
def test_imported_arm_passes_the_contract_and_its_flange_is_the_urdfs(imported, arm):
    pk = pytest.importorskip("pytorch_kinematics")
    torch = pytest.importorskip("torch")
    path, report = imported[arm]
    assert check_robot(path) == []
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    rel, _, flange_link = ARMS[arm]
    root = ET.parse(DATA / rel).getroot()
    for el in [*root.findall("transmission"), *root.findall("gazebo")]:  # pk's parser trips on xArm's
        root.remove(el)
    chain = pk.build_serial_chain_from_urdf(ET.tostring(root), flange_link).to(dtype=torch.float64)
    assert chain.get_joint_parameter_names() == report.joints
    q = np.random.default_rng(7).uniform(m.jnt_range[:, 0], m.jnt_range[:, 1], (1000, m.njnt))
    ref = chain.forward_kinematics(torch.tensor(q)).get_matrix().numpy()
    site = m.site("flange").id
    pos, rot = np.zeros((1000, 3)), np.zeros((1000, 3, 3))
    for i in range(1000):
        d.qpos[:] = q[i]
        mujoco.mj_kinematics(m, d)
        pos[i], rot[i] = d.site_xpos[site], d.site_xmat[site].reshape(3, 3)
    assert np.max(np.abs(pos - ref[:, :3, 3])) < 1e-6
    assert np.max(np.abs(rot - ref[:, :3, :3])) < 1e-6


@pytest.mark.parametrize("arm", list(ARMS))
def test_capsules_enclose_the_source_meshes_at_any_configuration(imported, arm):
    """The source's collision meshes, posed by C MuJoCo in the source model, lie inside the
    imported arm's capsules posed by C MuJoCo in the imported model (the frames, the fusing
    of fixed links and the fit checked at once)."""
    path, report = imported[arm]
    rel, _, _ = ARMS[arm]
    src = load_source(DATA / rel)
    sm, sd = src.model, mujoco.MjData(src.model)
    joints, _ = arm_chain(src)
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    caps = [g for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE]
    welded = {w.split(" at ")[0]: float(w.split(" at ")[1].split()[0]) for w in report.welded}
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(m.jnt_range[:, 0], m.jnt_range[:, 1])
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        sd.qpos[:] = 0
        for j, v in zip(joints, q, strict=True):
            sd.qpos[sm.jnt_qposadr[j]] = v
        for name, v in welded.items():
            sd.qpos[sm.jnt_qposadr[sm.joint(name).id]] = v
        mujoco.mj_kinematics(sm, sd)
        worst = 0.0
        for g in range(sm.ngeom):
            if sm.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH:
                continue
            mid = sm.geom_dataid[g]
            v = sm.mesh_vert[sm.mesh_vertadr[mid] : sm.mesh_vertadr[mid] + sm.mesh_vertnum[mid]]
            w = v @ sd.geom_xmat[g].reshape(3, 3).T + sd.geom_xpos[g]
            best = np.full(len(w), np.inf)
            for c in caps:
                axis = d.geom_xmat[c].reshape(3, 3)[:, 2] * m.geom_size[c][1]
                a, b = d.geom_xpos[c] - axis, d.geom_xpos[c] + axis
                ab = b - a
                t = np.clip((w - a) @ ab / (ab @ ab), 0, 1)
                best = np.minimum(best, np.linalg.norm(w - (a + t[:, None] * ab), axis=1) - m.geom_size[c][0])
            worst = max(worst, float(best.max()))
        assert worst < 1e-6, f"a vertex lies {worst * 1e3:.3f} mm outside every capsule"
    assert all(f.covered == 1.0 for f in report.fits)
    assert all(1.0 <= f.overestimate < 2.5 for f in report.fits)


def test_enclosing_circle_and_capsule_against_brute_force():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(60, 2))
    c, r = enclosing_circle(pts)
    assert np.max(np.linalg.norm(pts - c, axis=1)) <= r + 1e-9
    # brute force: the smallest circle through 2 or 3 of the points that holds all of them
    best = np.inf
    for i, j in itertools.combinations(range(len(pts)), 2):
        cc = (pts[i] + pts[j]) / 2
        rr = np.linalg.norm(pts[i] - cc)
        if np.all(np.linalg.norm(pts - cc, axis=1) <= rr + 1e-9):
            best = min(best, rr)
    for i, j, k in itertools.combinations(range(len(pts)), 3):
        a, b, e = pts[i], pts[j], pts[k]
        dd = 2 * (a[0] * (b[1] - e[1]) + b[0] * (e[1] - a[1]) + e[0] * (a[1] - b[1]))
        if abs(dd) < 1e-12:
            continue
        ux = (a @ a * (b[1] - e[1]) + b @ b * (e[1] - a[1]) + e @ e * (a[1] - b[1])) / dd
        uy = (a @ a * (e[0] - b[0]) + b @ b * (a[0] - e[0]) + e @ e * (b[0] - a[0])) / dd
        cc = np.array([ux, uy])
        rr = np.linalg.norm(a - cc)
        if rr < best and np.all(np.linalg.norm(pts - cc, axis=1) <= rr + 1e-9):
            best = rr
    assert abs(r - best) < 1e-9
    # points filling a known capsule give that capsule back (to the sampling's resolution)
    u = rng.normal(size=(20000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    surface = u * 0.05 + np.where(u[:, 2:] > 0, [0, 0, 0.1], [0, 0, -0.1])  # r 5 cm, segment z -0.1..0.1
    cap = capsule_along(surface, np.array([0.0, 0.0, 1.0]))
    assert abs(cap.r - 0.05) < 1e-3 and abs(np.linalg.norm(cap.b - cap.a) - 0.2) < 2e-3
    caps = fit_capsules(surface)
    assert coverage(surface, caps) == 1.0
    true_volume = np.pi * 0.05**2 * 0.2 + 4 / 3 * np.pi * 0.05**3
    assert abs(union_volume(caps) / true_volume - 1) < 0.03


URDF_HEAD = (
    '<robot name="t"><link name="a"><inertial><mass value="1"/>'
    '<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>'
    '<collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision></link>'
)


def _link(name: str) -> str:
    return URDF_HEAD.split("<link", 1)[1].replace('name="a"', f'name="{name}"').join(["<link", ""])


def _joint(name: str, kind: str, parent: str, child: str, extra: str = "") -> str:
    lim = '<limit lower="-1" upper="1" effort="10" velocity="1"/>' if kind != "continuous" else ""
    return (
        f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="0 0 0.2"/><axis xyz="0 0 1"/>{lim}{extra}</joint>'
    )


@pytest.mark.parametrize(
    "body, message",
    [
        ("", "no moving joints"),
        (
            _link("b")
            + _link("c")
            + _joint("j1", "revolute", "a", "b")
            + _joint("j2", "prismatic", "b", "c")
            + _link("d")
            + _joint("j3", "revolute", "c", "d"),
            "'j2' in the arm chain is prismatic",
        ),
        (
            _link("b")
            + _link("c")
            + _joint("j1", "revolute", "a", "b")
            + _joint("j2", "revolute", "b", "c", '<mimic joint="j1"/>'),
            "'j2' in the arm chain is a mimic joint",
        ),
        (
            _link("b") + _link("c") + _joint("j1", "revolute", "a", "b") + _joint("j2", "continuous", "b", "c"),
            "'j2' has no position limits: give --limit",
        ),
        (
            '<link name="m"><collision><geometry><mesh filename="package://nowhere/x.stl"/></geometry></collision>'
            "</link>" + _link("b") + _joint("j0", "fixed", "a", "m") + _joint("j1", "revolute", "a", "b"),
            "mesh package://nowhere/x.stl not found",
        ),
    ],
)
def test_bad_sources_are_refused_in_one_line(tmp_path, body, message):
    cmd = ["robot", "import", str(tmp_path / "t.urdf"), "--out", str(tmp_path / "o.xml"), "--qdd-max", "5"]
    src = tmp_path / "t.urdf"
    src.write_text(URDF_HEAD + body + "</robot>")
    with pytest.raises(SourceError, match=message.replace("(", r"\(").replace("+", r"\+")):
        import_robot(src, tmp_path / "o.xml", ImportOptions(qdd_max="5"))
    r = subprocess.run(
        [sys.executable, "-m", "lmjx.cli", *cmd],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "o.xml").exists()


def test_missing_limits_name_the_flag(tmp_path):
    src = tmp_path / "t.urdf"
    body = _link("b") + _link("c") + _joint("j1", "revolute", "a", "b") + _joint("j2", "revolute", "b", "c")
    src.write_text(URDF_HEAD + body.replace('velocity="1"', "") + "</robot>")
    with pytest.raises(SourceError, match=r"'j1' has no velocity limit in t\.urdf: give --qd-max"):
        import_robot(src, tmp_path / "o.xml", ImportOptions(qdd_max="5"))
    with pytest.raises(SourceError, match="give --qdd-max"):
        import_robot(src, tmp_path / "o.xml", ImportOptions(qd_max="2"))
    r = import_robot(src, tmp_path / "o.xml", ImportOptions(qd_max="2,3", qdd_max="5"))
    assert r.joints == ["j1", "j2"] and check_robot(tmp_path / "o.xml") == []
    m = mujoco.MjModel.from_xml_path(str(tmp_path / "o.xml"))
    assert list(m.numeric("lmjx_qd_max").data) == [2, 3]


def test_gripper_and_presets_on_a_bare_arm(tmp_path):
    """--gripper 2f85: the UR5e's stand-in, mounted on the flange axis where the last link's
    geometry ends (its box's top, 0.05 m), the tcp 0.145 m further; --preset: the loader's
    failure presets.  Bad presets and --tcp beside --gripper are refused in one line."""
    from lmjx.model.import_write import GRIPPERS
    from lmjx.model.robot import load_robot

    src = tmp_path / "t.urdf"
    body = _link("b") + _link("c") + _joint("j1", "revolute", "a", "b") + _joint("j2", "revolute", "b", "c")
    src.write_text(URDF_HEAD + body + "</robot>")
    out = tmp_path / "g.xml"
    opt = ImportOptions(qdd_max="5", gripper="2f85", presets=["stuck=J2=0.5", "other=j1=-1"])
    import_robot(src, out, opt)
    assert check_robot(out) == []
    m = mujoco.MjModel.from_xml_path(str(out))
    d = mujoco.MjData(m)
    for q in ([0.0, 0.0], [0.7, -0.4]):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        fl, tcp = d.site_xpos[m.site("flange").id], d.site_xpos[m.site("tcp").id]
        z = d.site_xmat[m.site("flange").id].reshape(3, 3)[:, 2]
        np.testing.assert_allclose(tcp, fl + (0.05 + GRIPPERS["2f85"].tcp[2]) * z, atol=1e-9)
    assert m.body(int(m.site("tcp").bodyid[0])).name == "gripper" and m.body("gripper").mass[0] == pytest.approx(0.925)
    robot = load_robot(str(out))
    assert robot.profile.presets == {"stuck": {2: 0.5}, "other": {1: -1.0}}
    import_robot(src, out, ImportOptions(qdd_max="5", gripper="2f85:0.1"))
    m = mujoco.MjModel.from_xml_path(str(out))
    assert m.body("gripper").pos[2] == pytest.approx(0.1)
    for bad, message in (
        (ImportOptions(qdd_max="5", gripper="2f85", tcp="c"), "drop --tcp"),
        (ImportOptions(qdd_max="5", gripper="robotiq"), "known grippers: 2f85"),
        (ImportOptions(qdd_max="5", presets=["x=J3=0"]), "not a lock of one of J1..J2"),
        (ImportOptions(qdd_max="5", presets=["x=J1=2"]), "outside the joint's range"),
        (ImportOptions(qdd_max="5", presets=["x=J1=0,J2=0"]), "locks every joint"),
    ):
        with pytest.raises(SourceError, match=message.replace(".", r"\.")):
            import_robot(src, tmp_path / "bad.xml", bad)
