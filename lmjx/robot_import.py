"""`lmjx robot import`: an lmjx robot MJCF (docs/ROBOTS.md) from a URDF or an MJCF with meshes.

The source is compiled by MuJoCo itself (a URDF with its mesh paths resolved, `package://`
from the URDF's folder and its parents; fixed links kept as bodies), which gives every link's
frame, inertial and collision geometry.  Then:

  * **the arm chain**: from the root down, the bodies whose subtree holds a moving joint,
    until the tree branches (a gripper's fingers) or ends; its hinge joints up to the last
    are the arm's joints.  A prismatic, mimic, ball or free joint among them is refused.
    Joints beyond the arm (a gripper's) are welded: hinges at 0 (or the range's nearest end),
    prismatic joints at their upper limit (open), each said in the output's header;
  * **the bodies**: one per arm joint, holding its link and every fixed link below it up to
    the next arm joint; the fixed links at the root form the static base; the `--tcp` link,
    when it is a fixed link past the last joint, becomes the tool body (its frame kept, so
    that the `tcp` site is not rotated in it).  Inertials of merged links are combined
    (masses, centres of mass, inertia tensors by the parallel-axis rule);
  * **collision capsules**: every merged body's collision geometry (mesh vertices, points on
    primitives' surfaces) is enclosed by 1-3 capsules (`lmjx.capsule_fit`); the share of
    vertices covered and the union's volume over the meshes' go in the header;
  * **limits**: position limits, velocity and effort from the source (URDF `<limit>`; an
    MJCF's `range` and `actuatorfrcrange`); a missing one is an error naming the joint and
    the flag that supplies it (`--qd-max`, `--tau-max`, `--limit` for continuous joints);
    acceleration limits exist in no URDF: `--qdd-max` is required;
  * **sites**: `flange` at the last arm link's frame (`--flange LINK` for another, e.g. the
    Panda's `panda_link8`), `tcp` in `--tcp LINK[:x,y,z]` (default: the last arm link),
    interaction points by the rule of `IP_RULES` (each overridable with `--ip`);
  * **self-collision exclusions**: the base and the first link (MuJoCo's parent filter skips
    static bodies), and any pair of bodies two joints apart whose capsules touch in at least
    `EXCLUDE_SHARE` of 1,000 seeded random configurations (touching at every angle, as the
    Panda's link 5 and link 7 housings do);
  * **a gripper** for a bare arm (`--gripper 2f85[:z]`): the shipped UR5e's stand-in, the
    envelope of a Robotiq 2F-85 opened to 85 mm (`GRIPPERS`), fixed at the flange's axis where
    the flange link's own collision geometry ends (or `z` m along it), its `tcp` between the
    fingertips; nothing is fitted to it (its capsules are the stand-in's);
  * **failure presets** (`--preset NAME=J2=0.3,J4=-1.5`) as `<text name="lmjx_failure_NAME">`;
  * the table, the actuators and the limits' numerics as the contract says.
"""

from __future__ import annotations

import datetime
import math
import shlex
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from .capsule_fit import Capsule, coverage, fit_capsules, hull_volume, segment_distance, union_volume
from .errors import ConfigError
from .fileio import write_text_atomic

MESH_EXTS = {".stl", ".obj", ".msh"}
EXCLUDE_SHARE = 0.95
PANDA_SPAN = 1.42  # [m] the shipped Panda's arm span (base axis to tcp), for the table's size
IP_RULES = {
    "hand": "at the tcp; size: the radius of the tool capsule holding it, else 6 mm",
    "wrist": "the middle of the longest capsule of the second-to-last joint's link; size: its radius",
    "forearm": "of the links of the joints in the arm's second half but the last two, the one with the "
    "longest capsule: that capsule's end nearest the next joint; size: its radius",
}


@dataclass(frozen=True)
class Gripper:
    """A gripper stand-in in its mount frame (z along the flange axis, y the opening direction)."""

    description: str
    mass: float  # [kg]
    com: tuple[float, float, float]  # [m]
    inertia: tuple[float, float, float]  # diagonal [kg m^2] about the centre of mass
    capsules: tuple[tuple[tuple[float, float, float], tuple[float, float, float], float], ...]  # (a, b, r)
    tcp: tuple[float, float, float]  # the grasp point [m]


GRIPPERS = {
    # the shipped UR5e's gripper (lmjx/assets/ur5e.xml): a Robotiq 2F-85 opened to 85 mm
    "2f85": Gripper(
        "an open parallel gripper stand-in, the envelope of a Robotiq 2F-85 opened to 85 mm (0.925 kg, "
        "fingers 85 mm apart, tcp 0.145 m from the mount); the shipped UR5e's",
        0.925,
        (0.0, 0.0, 0.055),
        (0.0012, 0.0014, 0.0009),
        (
            ((0.0, -0.03, 0.045), (0.0, 0.03, 0.045), 0.042),
            ((0.0, -0.045, 0.085), (0.0, 0.045, 0.085), 0.02),
            ((0.0, 0.0515, 0.1), (0.0, 0.0515, 0.146), 0.009),
            ((0.0, -0.0515, 0.1), (0.0, -0.0515, 0.146), 0.009),
        ),
        (0.0, 0.0, 0.145),
    ),
}
GRIPPER_BODY = "gripper"


class SourceError(ConfigError):
    """A source lmjx cannot import (one line, exit status 2)."""


@dataclass
class JointInfo:
    name: str
    kind: str  # revolute, continuous, prismatic, fixed, ball, free
    lower: float | None = None
    upper: float | None = None
    effort: float | None = None
    velocity: float | None = None
    mimic: bool = False


@dataclass
class Source:
    path: Path
    kind: str  # urdf or mjcf
    model: mujoco.MjModel
    joints: dict[str, JointInfo]  # by MuJoCo joint name
    name: str = ""  # the robot's or model's name in the file


@dataclass
class LinkFit:
    body: str
    capsules: list[Capsule]
    points: int
    covered: float  # share of the points inside a capsule
    geometry_volume: float  # [m^3]
    capsule_volume: float  # [m^3] of the union

    @property
    def overestimate(self) -> float:
        return self.capsule_volume / self.geometry_volume if self.geometry_volume > 0 else float("nan")


@dataclass
class ImportOptions:
    tcp: str | None = None  # LINK[:x,y,z]
    flange: str | None = None  # LINK
    qd_max: str | None = None
    qdd_max: str | None = None
    tau_max: str | None = None
    limit: float | None = None  # +-limit for continuous joints [rad]
    name: str | None = None
    ready: str | None = None
    ips: list[str] = field(default_factory=list)  # NAME=LINK:x,y,z[:r]
    gripper: str | None = None  # KIND[:z], a key of GRIPPERS and the mount's distance along the flange axis
    presets: list[str] = field(default_factory=list)  # NAME=J2=0.3,J4=-1.5


@dataclass
class ImportReport:
    out: Path
    joints: list[str]
    fits: list[LinkFit]
    welded: list[str]
    excluded: list[tuple[str, str]]
    notes: list[str]


# ---------------------------------------------------------------------------------------------
# loading the source


def _resolve_mesh(filename: str, base: Path) -> Path:
    if filename.startswith("package://"):
        pkg, _, sub = filename[len("package://") :].partition("/")
        for d in [base, *base.parents]:
            for cand in (d / pkg / sub, d / sub if d.name == pkg else None):
                if cand is not None and cand.is_file():
                    return cand
        raise SourceError(f"mesh {filename} not found in {base} or its parents (looked for {pkg}/{sub})")
    if filename.startswith("file://"):
        filename = filename[len("file://") :]
    p = Path(filename)
    p = p if p.is_absolute() else base / p
    if not p.is_file():
        raise SourceError(f"mesh {filename} not found (looked at {p})")
    return p


def _urdf_joints(root: ET.Element) -> dict[str, JointInfo]:
    out = {}
    for j in root.findall("joint"):
        lim = j.find("limit")

        def val(attr: str, lim: ET.Element | None = lim) -> float | None:
            v = lim.get(attr) if lim is not None else None
            return float(v) if v is not None else None

        out[j.get("name", "")] = JointInfo(
            name=j.get("name", ""),
            kind=j.get("type", "fixed"),
            lower=val("lower"),
            upper=val("upper"),
            effort=val("effort"),
            velocity=val("velocity"),
            mimic=j.find("mimic") is not None,
        )
    return out


def load_source(path: str | Path) -> Source:
    """Compile a URDF or an MJCF with MuJoCo; its joints' limits as the source states them."""
    p = Path(path)
    if not p.is_file():
        raise SourceError(f"no such file: {p}")
    try:
        root = ET.parse(p).getroot()
    except ET.ParseError as e:
        raise SourceError(f"{p} is not XML: {e}") from None
    if root.tag == "robot":
        joints = _urdf_joints(root)
        if not any(j.kind in ("revolute", "continuous", "prismatic") for j in joints.values()):
            raise SourceError(f"{p} has no moving joints (an arm needs revolute joints)")
        for mesh in root.iter("mesh"):
            f = _resolve_mesh(mesh.get("filename", ""), p.parent)
            if f.suffix.lower() not in MESH_EXTS:
                raise SourceError(
                    f"mesh {f.name}: MuJoCo reads {', '.join(sorted(MESH_EXTS))} meshes, not {f.suffix} "
                    "(convert it, e.g. with trimesh or Blender)"
                )
            mesh.set("filename", str(f))
        for old in root.findall("mujoco"):
            root.remove(old)
        mj = ET.SubElement(root, "mujoco")
        ET.SubElement(
            mj, "compiler", strippath="false", fusestatic="false", discardvisual="true", balanceinertia="true"
        )
        try:
            model = mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))
        except Exception as e:
            raise SourceError(f"MuJoCo cannot compile {p}: {' '.join(str(e).split())}") from None
        return Source(p, "urdf", model, joints, root.get("name") or p.stem)
    if root.tag == "mujoco":
        try:
            model = mujoco.MjModel.from_xml_path(str(p))
        except Exception as e:
            raise SourceError(f"MuJoCo cannot compile {p}: {' '.join(str(e).split())}") from None
        return Source(p, "mjcf", model, _mjcf_joints(model), root.get("model") or p.stem)
    raise SourceError(f"{p} is neither a URDF (<robot>) nor an MJCF (<mujoco>)")


def _mjcf_joints(m: mujoco.MjModel) -> dict[str, JointInfo]:
    mimic = set()
    for e in range(m.neq):
        if m.eq_type[e] == mujoco.mjtEq.mjEQ_JOINT:
            mimic.add(int(m.eq_obj1id[e]))
    kinds = {
        mujoco.mjtJoint.mjJNT_HINGE: "revolute",
        mujoco.mjtJoint.mjJNT_SLIDE: "prismatic",
        mujoco.mjtJoint.mjJNT_BALL: "ball",
        mujoco.mjtJoint.mjJNT_FREE: "free",
    }
    out = {}
    for j in range(m.njnt):
        name = m.joint(j).name or f"joint{j}"
        kind = kinds[m.jnt_type[j]]
        lo = hi = None
        if m.jnt_limited[j]:
            lo, hi = (float(v) for v in m.jnt_range[j])
        elif kind == "revolute":
            kind = "continuous"
        effort = float(m.jnt_actfrcrange[j][1]) if m.jnt_actfrclimited[j] else None
        if effort is None:
            for a in range(m.nu):
                joint_act = m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT and m.actuator_trnid[a][0] == j
                if joint_act and m.actuator_forcelimited[a]:
                    effort = float(max(abs(m.actuator_forcerange[a]))) * abs(float(m.actuator_gear[a][0]))
        out[name] = JointInfo(name, kind, lo, hi, effort, None, j in mimic)
    return out


# ---------------------------------------------------------------------------------------------
# the arm


def _children(m: mujoco.MjModel) -> dict[int, list[int]]:
    out: dict[int, list[int]] = {b: [] for b in range(m.nbody)}
    for b in range(1, m.nbody):
        out[int(m.body_parentid[b])].append(b)
    return out


def _subtree_moves(m: mujoco.MjModel, kids: dict[int, list[int]], b: int) -> bool:
    return m.body_jntnum[b] > 0 or any(_subtree_moves(m, kids, c) for c in kids[b])


def arm_chain(src: Source) -> tuple[list[int], list[int]]:
    """(arm joint ids in order, body ids along the chain from the root to its end)."""
    m = src.model
    kids = _children(m)
    path = [0]
    while True:
        moving = [c for c in kids[path[-1]] if _subtree_moves(m, kids, c)]
        if len(moving) != 1:
            break
        path.append(moving[0])
    joints = [int(m.body_jntadr[b]) + k for b in path for k in range(m.body_jntnum[b])]
    hinge = [j for j in joints if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    if not hinge:
        raise SourceError(f"{src.path}: no revolute joint in the arm chain")
    last = joints.index(hinge[-1])
    arm = joints[: last + 1]
    for j in arm:
        info = src.joints[m.joint(j).name]
        if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
            raise SourceError(f"joint '{info.name}' is free: lmjx arms stand on the table (remove the free joint)")
        if m.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
            raise SourceError(
                f"joint '{info.name}' in the arm chain is {info.kind}: lmjx arms have revolute joints only"
            )
        if info.mimic:
            raise SourceError(
                f"joint '{info.name}' in the arm chain is a mimic joint: lmjx arms have independent joints"
            )
    if len({int(m.jnt_bodyid[j]) for j in arm}) != len(arm):
        raise SourceError("a link in the arm chain carries more than one joint (lmjx arms have one per link)")
    return arm, path


def _numbers(text: str, what: str) -> list[float]:
    try:
        vals = [float(v) for v in str(text).split(",")]
    except ValueError:
        raise SourceError(f"{what} '{text}' is not a number or a comma-separated list of numbers") from None
    if not all(math.isfinite(v) for v in vals):
        raise SourceError(f"{what} '{text}': every value must be finite")
    return vals


def _per_joint(text: str | None, n: int, what: str) -> np.ndarray | None:
    """A positive limit per joint: one value for all, or n comma-separated."""
    if text is None:
        return None
    vals = _numbers(text, what)
    if len(vals) == 1:
        vals = vals * n
    if len(vals) != n or not all(v > 0 for v in vals):
        raise SourceError(f"{what} needs one positive value or {n} (one per arm joint), got '{text}'")
    return np.array(vals)


def _limits(src: Source, arm: list[int], opt: ImportOptions) -> tuple[np.ndarray, dict[str, np.ndarray], list[str]]:
    """(ranges (n, 2), {qd, qdd, tau}, notes on where each came from)."""
    m = src.model
    n = len(arm)
    infos = [src.joints[m.joint(j).name] for j in arm]
    notes = []
    ranges = np.zeros((n, 2))
    for i, info in enumerate(infos):
        if info.kind == "continuous" or info.lower is None or info.upper is None or info.upper <= info.lower:
            if opt.limit is None:
                raise SourceError(f"joint '{info.name}' has no position limits: give --limit V (+-V rad)")
            ranges[i] = (-opt.limit, opt.limit)
            notes.append(f"{info.name}: range +-{opt.limit:g} rad from --limit")
        else:
            ranges[i] = (info.lower, info.upper)
    out = {}
    for key, attr, flag, what in (
        ("qd", "velocity", "--qd-max", "velocity limit"),
        ("tau", "effort", "--tau-max", "effort (torque) limit"),
    ):
        given = _per_joint(getattr(opt, f"{key}_max"), n, flag)
        vals = []
        for i, info in enumerate(infos):
            v = getattr(info, attr)
            if given is not None:
                vals.append(given[i])
            elif v is None or not v > 0:
                raise SourceError(f"joint '{info.name}' has no {what} in {src.path.name}: give {flag}")
            else:
                vals.append(v)
        if given is not None:
            notes.append(f"{what}s from {flag}")
        out[key] = np.array(vals)
    qdd = _per_joint(opt.qdd_max, n, "--qdd-max")
    if qdd is None:
        raise SourceError(f"{src.path.name} gives no acceleration limits (no URDF does): give --qdd-max")
    out["qdd"] = qdd
    return ranges, out, notes


# ---------------------------------------------------------------------------------------------
# geometry


def _primitive_points(gtype: int, size: np.ndarray) -> tuple[np.ndarray, float]:
    """Points on a primitive's surface in its frame, and its volume."""
    g = mujoco.mjtGeom
    k = 24
    ang = np.linspace(0, 2 * np.pi, k, endpoint=False)
    if gtype == g.mjGEOM_BOX:
        s = np.array(size[:3])
        lin = np.linspace(-1, 1, 7)
        grid = np.array(np.meshgrid(lin, lin, lin)).reshape(3, -1).T
        pts = grid[np.any(np.abs(grid) == 1, axis=1)] * s
        return pts, float(8 * np.prod(s))
    if gtype == g.mjGEOM_SPHERE:
        r = float(size[0])
        i = np.arange(200) + 0.5
        phi, th = np.arccos(1 - 2 * i / 200), np.pi * (1 + 5**0.5) * i
        return r * np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], 1), 4 / 3 * np.pi * r**3
    if gtype in (g.mjGEOM_CYLINDER, g.mjGEOM_CAPSULE):
        r, h = float(size[0]), float(size[1])
        ring = np.stack([r * np.cos(ang), r * np.sin(ang)], 1)
        pts = [np.column_stack([ring, np.full(k, z)]) for z in np.linspace(-h, h, 5)]
        if gtype == g.mjGEOM_CAPSULE:
            pts += [np.array([[0, 0, h + r]]), np.array([[0, 0, -h - r]])]
            for z in (h, -h):
                for e in np.linspace(0.3, 1.3, 4):
                    pts.append(np.column_stack([ring * np.cos(e), np.full(k, z + np.sign(z) * r * np.sin(e))]))
            return np.concatenate(pts), np.pi * r * r * 2 * h + 4 / 3 * np.pi * r**3
        return np.concatenate(pts), np.pi * r * r * 2 * h
    if gtype == g.mjGEOM_ELLIPSOID:
        pts, _ = _primitive_points(g.mjGEOM_SPHERE, np.array([1.0]))
        return pts * np.array(size[:3]), 4 / 3 * np.pi * float(np.prod(size[:3]))
    raise SourceError(f"collision geometry of type {mujoco.mjtGeom(gtype).name} is not supported")


def _collision_points(m: mujoco.MjModel, d: mujoco.MjData, bodies: set[int]) -> tuple[np.ndarray, float]:
    """All collision points of the bodies (world frame) and their summed volume."""
    pts, vol = [], 0.0
    for g in range(m.ngeom):
        if m.geom_bodyid[g] not in bodies or not (m.geom_contype[g] or m.geom_conaffinity[g]):
            continue
        if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
            continue
        if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
            mid = int(m.geom_dataid[g])
            va, vn = int(m.mesh_vertadr[mid]), int(m.mesh_vertnum[mid])
            fa, fn = int(m.mesh_faceadr[mid]), int(m.mesh_facenum[mid])
            verts = np.array(m.mesh_vert[va : va + vn], dtype=np.float64)
            vol += hull_volume(verts)  # MuJoCo collides a mesh as its convex hull
            tri = verts[np.array(m.mesh_face[fa : fa + fn])]  # (f, 3, 3): the faces' centres and edge midpoints too
            local = np.concatenate([verts, tri.mean(1), (tri + np.roll(tri, 1, axis=1)).reshape(-1, 3) / 2])
        else:
            local, v = _primitive_points(int(m.geom_type[g]), m.geom_size[g])
            vol += v
        pts.append(local @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g])
    return (np.concatenate(pts) if pts else np.zeros((0, 3))), vol


@dataclass
class Frame:
    pos: np.ndarray
    rot: np.ndarray  # (3, 3)

    def inv_apply(self, p: np.ndarray) -> np.ndarray:
        return (p - self.pos) @ self.rot

    def relative(self, other: Frame) -> Frame:
        """other expressed in self."""
        return Frame(self.inv_apply(other.pos), self.rot.T @ other.rot)


def _quat(rot: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, rot.reshape(-1))
    return q


def _fmt(v: np.ndarray | list[float], digits: int = 9) -> str:
    return " ".join(f"{float(x):.{digits}g}" if abs(float(x)) > 1e-12 else "0" for x in v)


# ---------------------------------------------------------------------------------------------
# the import


def _parse_link_point(text: str, what: str) -> tuple[str, np.ndarray]:
    link, _, xyz = text.partition(":")
    if not xyz:
        return link, np.zeros(3)
    try:
        v = np.array([float(x) for x in xyz.split(",")])
    except ValueError:
        raise SourceError(f"{what} '{text}': the offset must be x,y,z in metres") from None
    if v.shape != (3,):
        raise SourceError(f"{what} '{text}': the offset must be three numbers x,y,z")
    return link, v


def import_robot(source: str | Path, out: str | Path, opt: ImportOptions, command: str | None = None) -> ImportReport:
    """Write an lmjx robot MJCF for `source` at `out` (atomically); what was done, for printing."""
    src = load_source(source)
    m = src.model
    arm, _ = arm_chain(src)
    n = len(arm)
    ranges, lim, notes = _limits(src, arm, opt)
    arm_bodies = [int(m.jnt_bodyid[j]) for j in arm]
    names = {m.body(b).name: b for b in range(m.nbody)}
    kids = _children(m)

    def subtree(b: int) -> list[int]:
        out = [b]
        for c in kids[b]:
            out += subtree(c)
        return out

    last_tree = set(subtree(arm_bodies[-1]))
    # the tool
    gripper, mount_z = _parse_gripper(opt)
    tcp_link, tcp_off = _parse_link_point(opt.tcp, "--tcp") if opt.tcp else (m.body(arm_bodies[-1]).name, np.zeros(3))
    if tcp_link not in names:
        raise SourceError(f"--tcp: no link '{tcp_link}' in {src.path.name}")
    tool = names[tcp_link]
    if tool not in last_tree:
        raise SourceError(f"--tcp: link '{tcp_link}' is not past the last arm joint ('{m.joint(arm[-1]).name}')")
    if m.body_jntnum[tool] > 0 and tool != arm_bodies[-1]:
        raise SourceError(f"--tcp: link '{tcp_link}' moves by a joint beyond the arm; name a link fixed to it")
    flange_link = opt.flange or m.body(arm_bodies[-1]).name
    if flange_link not in names:
        raise SourceError(f"--flange: no link '{flange_link}' in {src.path.name}")
    if names[flange_link] not in last_tree:
        raise SourceError(f"--flange: link '{flange_link}' is not past the last arm joint")
    presets = _presets(opt.presets, ranges)

    # the reference configuration: arm joints at 0; joints beyond the arm welded
    d = mujoco.MjData(m)
    welded = []
    for j in range(m.njnt):
        if j in arm:
            continue
        adr = int(m.jnt_qposadr[j])
        jt = m.jnt_type[j]
        if jt == mujoco.mjtJoint.mjJNT_FREE or jt == mujoco.mjtJoint.mjJNT_BALL:
            raise SourceError(f"joint '{m.joint(j).name}' is {src.joints[m.joint(j).name].kind}: not importable")
        lo, hi = (float(v) for v in m.jnt_range[j]) if m.jnt_limited[j] else (-np.inf, np.inf)
        if jt == mujoco.mjtJoint.mjJNT_SLIDE:
            v = hi if np.isfinite(hi) else 0.0
            why = "its upper limit (open)" if np.isfinite(hi) else "0"
        else:
            v = float(np.clip(0.0, lo, hi))
            why = "0" if v == 0 else "the end of its range nearest 0"
        d.qpos[adr] = v
        welded.append(f"{m.joint(j).name} at {v:g} ({why})")
    mujoco.mj_kinematics(m, d)

    def frame(b: int) -> Frame:
        return Frame(np.array(d.xpos[b]), np.array(d.xmat[b]).reshape(3, 3))

    # output bodies: base (static), one per arm joint, the tool (if a fixed link past the arm)
    separate_tool = tool != arm_bodies[-1]
    owner: dict[int, str] = {}
    out_bodies: list[tuple[str, int]] = [("base", 0)] + [(m.body(b).name, b) for b in arm_bodies]
    if separate_tool:
        out_bodies.append((m.body(tool).name, tool))
    heads = {b: nm for nm, b in out_bodies}

    def assign(b: int, cur: str) -> None:
        cur = heads.get(b, cur) if b != 0 else "base"
        owner[b] = cur
        for c in kids[b]:
            assign(c, cur)

    assign(0, "base")
    frames = {nm: (Frame(np.zeros(3), np.eye(3)) if b == 0 else frame(b)) for nm, b in out_bodies}
    parent_of = {}
    for nm, b in out_bodies[1:]:
        parent_of[nm] = owner[int(m.body_parentid[b])]

    # inertials and capsules per output body
    inertial: dict[str, tuple[float, np.ndarray, np.ndarray]] = {}
    fits: list[LinkFit] = []
    caps: dict[str, list[Capsule]] = {}
    for nm, _ in out_bodies:
        members = {b for b, o in owner.items() if o == nm and b != 0}
        f = frames[nm]
        mass = float(sum(m.body_mass[b] for b in members))
        if nm != "base" and mass <= 0:
            raise SourceError(f"link '{nm}' and the links fixed to it have no mass in {src.path.name}")
        if mass > 0:
            com = sum(m.body_mass[b] * d.xipos[b] for b in members) / mass
            inertia = np.zeros((3, 3))
            for b in members:
                if m.body_mass[b] <= 0:
                    continue
                r = d.ximat[b].reshape(3, 3)
                rr = d.xipos[b] - com
                shift = m.body_mass[b] * (rr @ rr * np.eye(3) - np.outer(rr, rr))  # parallel axes
                inertia += r @ np.diag(m.body_inertia[b]) @ r.T + shift
            inertial[nm] = (mass, f.inv_apply(com), f.rot.T @ inertia @ f.rot)
        # each source link keeps capsules of its own (a hand's fingers stay apart: the grasp
        # needs the space between them)
        caps[nm] = []
        for b in sorted(members):
            pts, vol = _collision_points(m, d, {b})
            if len(pts) == 0:
                continue
            local = f.inv_apply(pts)
            c = fit_capsules(local)
            caps[nm] += c
            fits.append(LinkFit(m.body(b).name, c, len(local), coverage(local, c), vol, union_volume(c)))
        if not caps[nm] and nm != "base" and not (separate_tool and nm == out_bodies[-1][0]):
            raise SourceError(f"link '{nm}' has no collision geometry in {src.path.name}")

    # sites
    sites: dict[str, list[tuple[str, np.ndarray, float, np.ndarray | None]]] = {nm: [] for nm, _ in out_bodies}
    fl = names[flange_link]
    fl_owner = owner[fl]
    rel = frames[fl_owner].relative(frame(fl))
    sites[fl_owner].append(("flange", rel.pos, 0.005, _quat(rel.rot)))
    tool_name = owner[tool] if not separate_tool else m.body(tool).name
    tcp_frame = frames[tool_name].relative(frame(tool))
    if not np.allclose(tcp_frame.rot, np.eye(3), atol=1e-9):
        raise SourceError(f"--tcp: link '{tcp_link}' is rotated in its body; name the last arm link or a fixed link")
    tcp_pos = tcp_frame.pos + tcp_off
    if gripper is not None:  # a body of its own on the flange's axis, the tcp in it
        if mount_z is None:
            pts, _ = _collision_points(m, d, {fl})
            mount_z = float(np.max(frame(fl).inv_apply(pts)[:, 2])) if len(pts) else 0.0
        f = frame(fl)
        frames[GRIPPER_BODY] = Frame(f.pos + mount_z * f.rot[:, 2], f.rot)
        parent_of[GRIPPER_BODY] = fl_owner
        out_bodies.append((GRIPPER_BODY, -1))
        sites[GRIPPER_BODY] = []
        caps[GRIPPER_BODY] = [Capsule(np.array(a), np.array(b), r) for a, b, r in gripper.capsules]
        inertial[GRIPPER_BODY] = (gripper.mass, np.array(gripper.com), np.diag(gripper.inertia))
        tool_name, tcp_pos = GRIPPER_BODY, np.array(gripper.tcp)
        tcp_link, tcp_off = f"{GRIPPER_BODY} ({opt.gripper}, {mount_z:.4g} m along the flange axis)", tcp_pos
    sites[tool_name].append(("tcp", tcp_pos, 0.006, None))
    ips = _interaction_points(caps, [m.body(b).name for b in arm_bodies], tool_name, tcp_pos, frames, opt)
    for ip_name, (body, pos, size) in ips.items():
        if body not in sites:
            raise SourceError(f"--ip {ip_name}: no body '{body}' in the imported arm (bodies: {', '.join(sites)})")
        sites[body].append((f"ip_{ip_name}", pos, size, None))

    ready = _joint_values(opt.ready, n, "--ready")
    if ready is not None and np.any((ready < ranges[:, 0]) | (ready > ranges[:, 1])):
        raise SourceError("--ready: a value is outside its joint's range")
    span = float(np.linalg.norm(tcp_pos)) + sum(
        float(np.linalg.norm(frames[nm].pos - frames[parent_of[nm]].pos))
        for nm in parent_of
        if nm != m.body(arm_bodies[0]).name
    )
    name = opt.name or f"lmjx_{src.name}"

    def mjcf(excludes: list[tuple[str, str]], header: str = "") -> str:
        return _write_mjcf(name, src, m, arm, arm_bodies, out_bodies, parent_of, frames, inertial, caps, sites,
                           ranges, lim, ready, span, excludes=excludes, header=header,
                           presets=presets)  # fmt: skip

    # the exclusions are found on the model itself: once without them but the base's
    excludes = [("base", m.body(arm_bodies[0]).name)]
    excludes += _touching_pairs(mjcf(excludes), out_bodies, parent_of)
    header = _header(
        src, command, arm, m, ranges, lim, notes, welded, fits, excludes, ips, tcp_link, tcp_off, flange_link
    )
    extra = []
    if gripper is not None:
        extra.append(f"Gripper (--gripper {opt.gripper}; given, not fitted): {gripper.description}.")
    if presets:
        extra.append("Failure presets (--preset): " + "; ".join(f"{k} {v}" for k, v in presets.items()) + ".")
    header += "".join("\n  " + e.replace("--", "- -") for e in extra)  # no "--" inside an XML comment
    text = mjcf(excludes, header)
    out = Path(out)
    write_text_atomic(out, text)
    return ImportReport(out, [m.joint(j).name for j in arm], fits, welded, excludes, notes)


def _parse_gripper(opt: ImportOptions) -> tuple[Gripper | None, float | None]:
    """--gripper KIND[:z]: the stand-in and the mount's distance along the flange axis (None:
    where the flange link's geometry ends)."""
    if opt.gripper is None:
        return None, None
    kind, _, z = opt.gripper.partition(":")
    if kind not in GRIPPERS:
        raise SourceError(f"--gripper '{opt.gripper}': known grippers: {', '.join(GRIPPERS)} (e.g. --gripper 2f85)")
    if opt.tcp is not None:
        raise SourceError("--gripper places the tcp between its fingertips: drop --tcp")
    mount = None
    if z:
        mount = _numbers(z, "--gripper mount")[0]
        if not 0 <= mount <= 1:
            raise SourceError(f"--gripper '{opt.gripper}': the mount's distance must be 0..1 m")
    return GRIPPERS[kind], mount


def _presets(specs: list[str], ranges: np.ndarray) -> dict[str, str]:
    """--preset NAME=J2=0.3,J4=-1.5 (repeatable): {name: spec}, each joint J1..Jn once, within
    its range."""
    n = len(ranges)
    out = {}
    for spec in specs:
        name, _, locks = spec.partition("=")
        if not name or not all(c.isalnum() or c in "_-" for c in name) or not locks:
            raise SourceError(f"--preset '{spec}': write NAME=J2=0.3,J4=-1.5 (NAME of letters, digits, _ or -)")
        if name == "none" or name in out:
            raise SourceError(f"--preset '{spec}': the name '{name}' is reserved or given twice")
        parts = []
        seen = set()
        for part in locks.split(","):
            j, _, v = part.strip().partition("=")
            j = j.strip().upper()
            if not j.startswith("J") or not j[1:].isdigit() or not 1 <= int(j[1:]) <= n or int(j[1:]) in seen:
                raise SourceError(f"--preset '{spec}': '{part}' is not a lock of one of J1..J{n} (each once)")
            k, a = int(j[1:]), _numbers(v, f"--preset {name}")[0]
            if not ranges[k - 1, 0] <= a <= ranges[k - 1, 1]:
                raise SourceError(
                    f"--preset '{spec}': J{k}={a:g} is outside the joint's range [{ranges[k - 1, 0]:.4g}, "
                    f"{ranges[k - 1, 1]:.4g}]"
                )
            seen.add(k)
            parts.append(f"J{k}={a:.9g}")
        if len(seen) >= n:
            raise SourceError(f"--preset '{spec}': locks every joint")
        out[name] = ",".join(parts)
    return out


def _joint_values(text: str | None, n: int, what: str) -> np.ndarray | None:
    """Exactly n joint values (a pose) [rad]."""
    if text is None:
        return None
    vals = _numbers(text, what)
    if len(vals) != n:
        raise SourceError(f"{what} needs {n} values (one per arm joint), got {len(vals)}")
    return np.array(vals)


def _interaction_points(
    caps: dict[str, list[Capsule]],
    arm_links: list[str],
    tool: str,
    tcp: np.ndarray,
    frames: dict[str, Frame],
    opt: ImportOptions,
) -> dict[str, tuple[str, np.ndarray, float]]:
    """ip_hand, ip_wrist, ip_forearm by the rule of IP_RULES, then the --ip overrides."""
    out: dict[str, tuple[str, np.ndarray, float]] = {}
    n = len(arm_links)
    size = 0.006
    for c in caps.get(tool, []):
        if segment_distance(tcp[None], c.a, c.b)[0] <= c.r:
            size = c.r
    out["hand"] = (tool, tcp, size)

    def longest(link: str) -> Capsule | None:
        cs = caps.get(link, [])
        return max(cs, key=lambda c: float(np.linalg.norm(c.b - c.a)) + 2 * c.r) if cs else None

    if n >= 2:
        c = longest(arm_links[n - 2])
        if c is not None:
            out["wrist"] = (arm_links[n - 2], (c.a + c.b) / 2, c.r)
    cands = [arm_links[i] for i in range(n // 2, max(n - 2, n // 2)) if longest(arm_links[i]) is not None]
    if not cands and n >= 3:
        cands = [arm_links[n - 3]] if longest(arm_links[n - 3]) is not None else []
    if cands:
        link = max(cands, key=lambda nm: float(np.linalg.norm(longest(nm).b - longest(nm).a)))  # type: ignore[union-attr]
        c = longest(link)
        assert c is not None
        nxt = arm_links[arm_links.index(link) + 1]
        child = frames[link].inv_apply(frames[nxt].pos)
        end = c.a if np.linalg.norm(c.a - child) < np.linalg.norm(c.b - child) else c.b
        out["forearm"] = (link, end, c.r)
    for spec in opt.ips:
        nm, _, rest = spec.partition("=")
        parts = rest.split(":")
        if not nm or len(parts) < 2:
            raise SourceError(f"--ip '{spec}': write NAME=LINK:x,y,z[:r]")
        link, pos = _parse_link_point(":".join(parts[:2]), "--ip")
        r = float(parts[2]) if len(parts) > 2 else 0.02
        out[nm] = (link, pos, r)
    return out


def _touching_pairs(text: str, out_bodies: list[tuple[str, int]], parent_of: dict[str, str]) -> list[tuple[str, str]]:
    """Pairs of bodies two joints apart whose capsules touch in >= EXCLUDE_SHARE of 1,000
    seeded random configurations."""
    m = mujoco.MjModel.from_xml_string(text)
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    lo, hi = m.jnt_range[:, 0], m.jnt_range[:, 1]
    grand = {(parent_of[parent_of[c]], c) for c in parent_of if parent_of[c] in parent_of}
    counts = {p: 0 for p in grand}
    trials = 1000
    for _ in range(trials):
        d.qpos[:] = rng.uniform(lo, hi)
        mujoco.mj_forward(m, d)
        seen = set()
        for c in d.contact[: d.ncon]:
            b1, b2 = m.body(int(m.geom_bodyid[c.geom1])).name, m.body(int(m.geom_bodyid[c.geom2])).name
            for p in ((b1, b2), (b2, b1)):
                if p in counts and p not in seen:
                    seen.add(p)
                    counts[p] += 1
    return sorted(p for p, k in counts.items() if k >= EXCLUDE_SHARE * trials)


def _header(
    src, command, arm, m, ranges, lim, notes, welded, fits, excludes, ips, tcp_link, tcp_off, flange_link
) -> str:
    lines = [
        f"Imported for lmjx by `lmjx robot import` on {datetime.date.today().isoformat()} from {src.path.name}"
        f" ({src.kind.upper()}).",
        f"Command: {command or '(Python API)'}",
        "",
        "Joints (range [rad], velocity [rad/s], acceleration [rad/s^2], torque [Nm]):",
    ]
    for i, j in enumerate(arm):
        lines.append(
            f"  J{i + 1} {m.joint(j).name}: [{ranges[i, 0]:.6g}, {ranges[i, 1]:.6g}], qd {lim['qd'][i]:g}, "
            f"qdd {lim['qdd'][i]:g}, tau {lim['tau'][i]:g}"
        )
    lines += ["From the source unless said: " + ("; ".join(notes) if notes else "every limit but acceleration") + ";"]
    lines += ["acceleration limits from --qdd-max."]
    if welded:
        lines += ["Welded (joints beyond the arm): " + "; ".join(welded) + "."]
    lines += [
        f"flange: the frame of link '{flange_link}'; tcp: link '{tcp_link}' + ({_fmt(tcp_off, 6)}) m.",
        "Interaction points: " + "; ".join(f"ip_{k} on {v[0]} (r {v[2]:.3f} m)" for k, v in ips.items()) + ".",
        "Excluded from self-collision: " + "; ".join(f"{a}-{b}" for a, b in excludes) + ".",
        "",
        "Collision capsules (lmjx.capsule_fit: every vertex enclosed; the union's volume over the",
        "collision geometry's):",
        "  link: capsules, vertices covered, geometry volume [l], capsules [l], ratio",
    ]
    for f in fits:
        lines.append(
            f"  {f.body}: {len(f.capsules)}, {100 * f.covered:.1f} % of {f.points}, {1e3 * f.geometry_volume:.3f}, "
            f"{1e3 * f.capsule_volume:.3f}, {f.overestimate:.2f}"
        )
    return "\n".join("  " + ln if ln else "" for ln in lines).replace("--", "- -")


def _write_mjcf(
    name,
    src,
    m,
    arm,
    arm_bodies,
    out_bodies,
    parent_of,
    frames,
    inertial,
    caps,
    sites,
    ranges,
    lim,
    ready,
    span,
    excludes,
    header="",
    presets=None,
) -> str:
    scale = max(1.0, span / PANDA_SPAN)
    L = []
    if header:
        L += ["<!--", header, "-->"]
    L += [
        f'<mujoco model="{name}">',
        '  <compiler angle="radian" autolimits="true"/>',
        '  <option timestep="0.002" integrator="implicitfast"/>',
        "  <default>",
        '    <default class="arm">',
        '      <joint type="hinge" damping="0" armature="0"/>',
        '      <geom type="capsule" contype="1" conaffinity="1" condim="3" friction="0.8 0.005 0.0001" '
        'rgba="0.75 0.75 0.78 1" group="0"/>',
        '      <site group="3" rgba="1 0.3 0.1 0.6"/>',
        '      <position kp="1000" kv="60"/>',
        "    </default>",
        "  </default>",
        "  <custom>",
        f'    <numeric name="lmjx_qd_max" data="{_fmt(lim["qd"], 6)}"/>',
        f'    <numeric name="lmjx_qdd_max" data="{_fmt(lim["qdd"], 6)}"/>',
    ]
    if ready is not None:
        L.append(f'    <numeric name="lmjx_ready" data="{_fmt(ready, 9)}"/>')
    for k, v in (presets or {}).items():
        L.append(f'    <text name="lmjx_failure_{k}" data="{v}"/>')
    L += [
        "  </custom>",
        '  <visual><global offwidth="1280" offheight="960"/></visual>',
        "  <asset>",
        '    <texture name="grid" type="2d" builtin="checker" rgb1="0.55 0.45 0.35" rgb2="0.6 0.5 0.4" width="256" '
        'height="256"/>',
        '    <material name="wood" texture="grid" texrepeat="8 8" reflectance="0.05"/>',
        "  </asset>",
        "  <worldbody>",
        '    <light name="top" pos="0.4 0 2.5" dir="0 0 -1" diffuse="0.8 0.8 0.8"/>',
        f'    <geom name="table" type="box" pos="{0.35 * scale:.6g} 0 -0.2" '
        f'size="{0.85 * scale:.6g} {1.1 * scale:.6g} 0.2" material="wood" contype="1" conaffinity="1" '
        'friction="0.5 0.005 0.0001"/>',
    ]
    children: dict[str, list[str]] = {}
    for c, p in parent_of.items():
        children.setdefault(p, []).append(c)
    joint_of = {int(m.jnt_bodyid[j]): (i, j) for i, j in enumerate(arm)}
    body_id = dict(out_bodies)

    def emit(nm: str, depth: int) -> None:
        ind = "  " * depth
        if nm == "base":
            L.append(f'{ind}<body name="base" childclass="arm">')
        else:
            rel = frames[parent_of[nm]].relative(frames[nm])
            L.append(f'{ind}<body name="{nm}" pos="{_fmt(rel.pos)}" quat="{_fmt(_quat(rel.rot))}">')
        if nm in inertial:
            mass, com, inert = inertial[nm]
            full = [inert[0, 0], inert[1, 1], inert[2, 2], inert[0, 1], inert[0, 2], inert[1, 2]]
            L.append(f'{ind}  <inertial pos="{_fmt(com)}" mass="{mass:.9g}" fullinertia="{_fmt(full)}"/>')
        b = body_id[nm]
        if b in joint_of:
            i, j = joint_of[b]
            L.append(
                f'{ind}  <joint name="{m.joint(j).name}" axis="{_fmt(m.jnt_axis[j])}" range="{_fmt(ranges[i])}" '
                f'actuatorfrcrange="{-lim["tau"][i]:.6g} {lim["tau"][i]:.6g}"/>'
            )
        for k, c in enumerate(caps.get(nm, [])):
            L.append(f'{ind}  <geom name="{nm}_c{k}" fromto="{_fmt(c.a)}  {_fmt(c.b)}" size="{c.r:.6g}"/>')
        for sname, pos, size, quat in sites.get(nm, []):
            q = f' quat="{_fmt(quat)}"' if quat is not None and not np.allclose(quat, [1, 0, 0, 0], atol=1e-12) else ""
            L.append(f'{ind}  <site name="{sname}" pos="{_fmt(pos)}" size="{size:.6g}"{q}/>')
        for c in children.get(nm, []):
            emit(c, depth + 1)
        L.append(f"{ind}</body>")

    emit("base", 2)
    L += ["  </worldbody>", "  <contact>"]
    for a, b in excludes:
        L.append(f'    <exclude body1="{a}" body2="{b}"/>')
    L += ["  </contact>", "  <actuator>"]
    for j in arm:
        jn = m.joint(j).name
        L.append(f'    <position name="{jn}" joint="{jn}" class="arm"/>')
    L += ["  </actuator>", "</mujoco>", ""]
    return "\n".join(L)


def command_line() -> str:
    return "lmjx " + " ".join(shlex.quote(a) for a in sys.argv[1:])
