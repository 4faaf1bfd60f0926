"""The source of `lmjx robot import`, read: a URDF or an MJCF compiled by MuJoCo (mesh paths
resolved), its joints with their limits, the arm chain, and points on each link's collision
geometry for the capsule fit.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from lmjx.errors import ConfigError
from lmjx.model.capsule_fit import hull_volume

MESH_EXTS = {".stl", ".obj", ".msh"}


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
