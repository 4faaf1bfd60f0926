"""The robot: loads an arm's MJCF once and exposes everything else derives from it.

`load_robot(name_or_path)` returns a `Robot` holding the compiled MuJoCo model, the static
`ArmModel` the kernels consume (kinematic tree, capsules, checked pairs, sites), joint limits,
the interaction points, and the robot's profile (its failure presets, the "real" world's
servo gains, the scale of the scenarios).  Shipped robots (`ROBOTS`): the Franka Panda
(`panda`, the default) and the Universal Robots UR5e (`ur5e`); any other MJCF that meets
the contract of docs/ROBOTS.md loads by its path (`check_robot` lists what it lacks).
Nothing here computes kinematics; the kernels do.
"""

from __future__ import annotations

import functools
import hashlib
import math
import threading
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from kernels.dynamics import Inertials
from kernels.math3 import quat_to_mat
from kernels.model import ArmModel, Tree
from lmjx.errors import ConfigError, LmjxError

ASSETS = Path(__file__).parent / "assets"
MODEL_PATH = ASSETS / "panda.xml"
DEFAULT_ROBOT = "panda"
TCP_SITE = "tcp"
FLANGE_SITE = "flange"
TABLE_GEOM = "table"
IP_PREFIX = "ip_"
DEFAULT_IPS = ("hand", "wrist", "forearm")
FAILURE_TEXT = "lmjx_failure_"  # <custom><text name="lmjx_failure_NAME" data="J2=0.3,J4=-1.5"/>: a preset


class RobotError(LmjxError):
    """A robot description that does not meet lmjx's contract (docs/ROBOTS.md)."""

    def __init__(self, path: str | Path, problems: list[str]) -> None:
        self.problems = problems
        super().__init__(
            f"{path} is not an lmjx robot: {problems[0]}"
            + (f" (and {len(problems) - 1} more: lmjx robot check {path})" if len(problems) > 1 else "")
        )


@dataclass(frozen=True)
class RobotProfile:
    """What lmjx knows of a robot beyond its MJCF."""

    # Failure presets: name -> {joint number (1-based): lock angle [rad]}.  docs/ROBOTS.md
    # and docs/DETAILS.md say how each was chosen.
    presets: dict[str, dict[int, float]] = field(default_factory=dict)
    # The "real" world's joint servo gains (Franka-like impedance); None: from the torque limits.
    real_kp: tuple[float, ...] | None = None
    real_kv: tuple[float, ...] | None = None
    # The scenarios' table positions are scaled by this (the Panda's layouts at 1.0).  A
    # user's robot: its `arm_span` over the Panda's.
    task_scale: float = 1.0
    description: str = ""


PROFILES: dict[str, RobotProfile] = {
    # Panda (docs/DETAILS.md, "Failure cases"): case1 from `lmjx lock-search --joints J3,J5 --base
    # J7=0.785398 --grid 7 --match 0.7294,0.9239`; case2 from `lmjx lock-search --joints J6,J7
    # --grid 9`.
    "panda": RobotProfile(
        presets={"case1": {3: 2.8773, 5: 0.0, 7: math.pi / 4}, "case2": {6: 0.935, 7: -0.7193}},
        real_kp=(600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0),
        real_kv=(50.0, 50.0, 50.0, 50.0, 30.0, 25.0, 15.0),
        task_scale=1.0,
        description="Franka Emika Panda, 7 joints, Franka Hand (fingers welded open)",
    ),
    # UR5e (docs/ROBOTS.md): presets from lock searches like the Panda's: case1 from `lmjx
    # lock-search --robot ur5e --joints J4,J5 --grid 9 --cell 0.04 --match 0.7294,0.9239`
    # (the lock closest to the paper's case-1 ratios); case2 from `lmjx lock-search --robot
    # ur5e --joints J5,J6 --grid 9 --cell 0.04` (J5 = -6.2632 rad is 0.02 rad from the wrist's
    # straight pose, where the tool axis lies along the wrist 1 axis).
    "ur5e": RobotProfile(
        presets={"case1": {4: 4.6974, 5: 1.5658}, "case2": {5: -6.2632, 6: 0.0}},
        real_kp=(600.0, 600.0, 600.0, 250.0, 150.0, 50.0),
        real_kv=(50.0, 50.0, 50.0, 30.0, 25.0, 15.0),
        task_scale=1.0,
        description="Universal Robots UR5e, 6 joints, open parallel-gripper stand-in",
    ),
}
ROBOTS: dict[str, Path] = {"panda": MODEL_PATH, "ur5e": ASSETS / "ur5e.xml"}


@dataclass(frozen=True, eq=False)
class Robot:
    """An arm on its table, as every part of lmjx sees it."""

    path: Path
    key: str  # the shipped name ("panda", "ur5e") or the MJCF's path
    name: str  # the MJCF's model name
    model_hash: str  # sha256 of the MJCF text
    mj: mujoco.MjModel
    arm: ArmModel
    joint_names: tuple[str, ...]
    lower: np.ndarray  # (nq,) position limits [rad]
    upper: np.ndarray
    qd_max: np.ndarray  # (nq,) velocity limits [rad/s]
    qdd_max: np.ndarray  # (nq,) acceleration limits [rad/s^2]
    jerk_max: np.ndarray  # (nq,) jerk limits [rad/s^3] (inf where the model gives none)
    tau_max: np.ndarray  # (nq,) torque limits [Nm]
    friction: np.ndarray  # (3, nq) Gaz et al. friction parameters phi1, phi2, phi3 (zeros: none)
    inertials: Inertials
    ready: np.ndarray  # (nq,) a pose to park in (the model's lmjx_ready, else zeros)
    site_names: tuple[str, ...]
    profile: RobotProfile = field(default_factory=RobotProfile)
    interaction_points: dict[str, int] = field(default_factory=dict)  # name -> site index
    tcp_site: int = 0
    flange_site: int = 0

    @property
    def nq(self) -> int:
        return len(self.joint_names)

    @property
    def tool_body_name(self) -> str:
        """The name of the body that carries the grasp point (the gripper or hand)."""
        return self.mj.body(int(self.mj.site_bodyid[self.tcp_site])).name

    @property
    def default_ips(self) -> tuple[str, ...]:
        """The interaction points maps use unless told otherwise: hand, wrist and forearm where
        the model has all three (both shipped arms do), else every `ip_` site it has."""
        if all(n in self.interaction_points for n in DEFAULT_IPS):
            return DEFAULT_IPS
        return tuple(self.interaction_points)

    @property
    def maps_dir(self) -> str:
        """Where its maps go by default: maps/ for the Panda, maps/<name>/ for any other."""
        if self.key == DEFAULT_ROBOT:
            return "maps"
        safe = "".join(c if c.isalnum() or c in "-._" else "_" for c in (self.key if self.key in ROBOTS else self.name))
        return f"maps/{safe}"

    def site_index(self, name: str) -> int:
        return self.site_names.index(name)

    def __repr__(self) -> str:
        presets = ", ".join(["none", *self.profile.presets])
        ips = ", ".join(self.interaction_points)
        return (
            f"Robot({self.key!r}: {self.name}, {self.nq} joints, failures {presets}; interaction points {ips}; "
            f"model {self.model_hash[:12]})"
        )


def _numeric(m: mujoco.MjModel, name: str) -> np.ndarray:
    return np.array(m.numeric(name).data, dtype=np.float64)


def _tree(m: mujoco.MjModel) -> Tree:
    nb = m.nbody - 1  # body 0 is the world
    parent = np.array([m.body_parentid[b] - 1 for b in range(1, m.nbody)], dtype=np.int32)
    joint = -np.ones(nb, dtype=np.int32)
    for j in range(m.njnt):
        if m.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
            raise ValueError(f"joint {m.joint(j).name}: lmjx supports hinge joints only")
        b = m.jnt_bodyid[j] - 1
        if joint[b] >= 0:
            raise ValueError(f"body {m.body(b + 1).name} has more than one joint")
        joint[b] = j
    rot = np.stack([quat_to_mat(m.body_quat[b]) for b in range(1, m.nbody)])
    pos = np.array(m.body_pos[1:], dtype=np.float64)
    axis = np.array(m.jnt_axis, dtype=np.float64)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    anchor = np.array(m.jnt_pos, dtype=np.float64)
    joint_body = np.array(m.jnt_bodyid - 1, dtype=np.int32)
    ancestors = np.zeros((nb, m.njnt))
    for b in range(nb):
        a = b
        while a >= 0:
            if joint[a] >= 0:
                ancestors[b, joint[a]] = 1.0
            a = parent[a]
    return Tree(parent, joint, pos, rot, axis, anchor, joint_body, ancestors)


def _inertials(m: mujoco.MjModel) -> Inertials:
    """Mass, COM and inertia tensor (body frame) of every body but the world."""
    inertia = []
    for b in range(1, m.nbody):
        r = quat_to_mat(m.body_iquat[b])
        inertia.append(r @ np.diag(m.body_inertia[b]) @ r.T)
    return Inertials(
        mass=np.array(m.body_mass[1:], dtype=np.float64),
        com=np.array(m.body_ipos[1:], dtype=np.float64),
        inertia=np.array(inertia),
        gravity=np.array(m.opt.gravity, dtype=np.float64),
    )


def _pair_is_checked(m: mujoco.MjModel, g1: int, g2: int) -> bool:
    """Whether C MuJoCo's broad-phase filters would let geoms g1, g2 collide."""
    b1, b2 = m.geom_bodyid[g1], m.geom_bodyid[g2]
    w1, w2 = m.body_weldid[b1], m.body_weldid[b2]
    if w1 == w2:
        return False
    if not (m.geom_contype[g1] & m.geom_conaffinity[g2] or m.geom_contype[g2] & m.geom_conaffinity[g1]):
        return False
    filter_parent = not (m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT)
    if filter_parent and w1 != 0 and w2 != 0:
        p1 = m.body_weldid[m.body_parentid[w1]]
        p2 = m.body_weldid[m.body_parentid[w2]]
        if p1 == w2 or p2 == w1:
            return False
    lo, hi = sorted((int(b1), int(b2)))
    signatures = set(int(s) for s in m.exclude_signature)
    return ((lo << 16) + hi) not in signatures


def _arm_model(m: mujoco.MjModel) -> ArmModel:
    tree = _tree(m)
    caps = [g for g in range(m.ngeom) if m.geom_bodyid[g] != 0 and (m.geom_contype[g] or m.geom_conaffinity[g])]
    for g in caps:
        if m.geom_type[g] != mujoco.mjtGeom.mjGEOM_CAPSULE:
            raise ValueError(f"robot collision geom {m.geom(g).name} must be a capsule")
    cap_body = np.array([m.geom_bodyid[g] - 1 for g in caps], dtype=np.int32)
    rot = [quat_to_mat(m.geom_quat[g]) for g in caps]
    half = np.array([m.geom_size[g][1] for g in caps])
    centre = np.array([m.geom_pos[g] for g in caps])
    axis = np.array([r[:, 2] for r in rot])
    cap_a = centre - axis * half[:, None]
    cap_b = centre + axis * half[:, None]
    cap_r = np.array([m.geom_size[g][0] for g in caps])
    pairs = np.array(
        [(i, j) for i in range(len(caps)) for j in range(i + 1, len(caps)) if _pair_is_checked(m, caps[i], caps[j])],
        dtype=np.int32,
    ).reshape(-1, 2)
    table = m.geom(TABLE_GEOM)
    table_caps = np.array([i for i, g in enumerate(caps) if _pair_is_checked(m, g, table.id)], dtype=np.int32)
    table_z = float(table.pos[2] + table.size[2])
    return ArmModel(
        tree=tree,
        lower=np.array(m.jnt_range[:, 0]),
        upper=np.array(m.jnt_range[:, 1]),
        site_body=np.array(m.site_bodyid - 1, dtype=np.int32),
        site_pos=np.array(m.site_pos, dtype=np.float64),
        site_radius=np.array(m.site_size[:, 0], dtype=np.float64),
        tool_body=int(m.site_bodyid[m.site(TCP_SITE).id] - 1),
        cap_body=cap_body,
        cap_a=cap_a,
        cap_b=cap_b,
        cap_r=cap_r,
        self_pairs=pairs,
        table_caps=table_caps,
        table_z=table_z,
        table_center=np.array(table.pos, dtype=np.float64),
        table_rot=quat_to_mat(table.quat),
        table_half=np.array(table.size, dtype=np.float64),
    )


def resolve_robot(name_or_path: str | Path | None = None) -> tuple[str, Path]:
    """(key, MJCF path) of a shipped robot's name or of a path to an MJCF."""
    text = str(name_or_path) if name_or_path is not None else DEFAULT_ROBOT
    if text in ROBOTS:
        return text, ROBOTS[text]
    p = Path(text)
    if p.suffix.lower() == ".xml" or p.exists():
        if not p.is_file():
            raise ConfigError(f"no robot description at {p}")
        if p.resolve() in {v.resolve() for v in ROBOTS.values()}:
            key = next(k for k, v in ROBOTS.items() if v.resolve() == p.resolve())
            return key, ROBOTS[key]
        return str(p), p
    raise ConfigError(f"unknown robot '{text}'; the shipped robots are {', '.join(ROBOTS)}, or give an MJCF's path")


def as_robot(robot: Robot | str | Path | None = None) -> Robot:
    """The robot an argument names: a `Robot` as it is, a shipped robot's name ("panda", the
    default for None; "ur5e") or an MJCF's path (loaded once, see `load_robot`)."""
    if isinstance(robot, Robot):
        return robot
    if robot is not None and not isinstance(robot, str | Path):
        raise ConfigError(f"a robot is a name ({', '.join(ROBOTS)}), an MJCF's path or a Robot, not {robot!r}")
    return load_robot(robot)


def check_robot(path: str | Path) -> list[str]:
    """Everything an MJCF lacks to be an lmjx robot (docs/ROBOTS.md), one sentence each; []
    when it meets the contract."""
    p = Path(path)
    try:
        m = mujoco.MjModel.from_xml_path(str(p))
    except Exception as e:  # MuJoCo's own parse and compile errors
        text = "; ".join(line.strip() for line in str(e).strip().splitlines() if line.strip())
        return [f"MuJoCo cannot load it: {text or type(e).__name__}"]  # the whole message, on one line
    problems: list[str] = []
    nq = m.njnt
    if nq < 2:
        problems.append(f"it has {nq} joint(s); an arm needs at least 2 hinge joints")
    for j in range(m.njnt):
        name = m.joint(j).name or f"joint {j}"
        if m.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
            problems.append(f"joint '{name}' is not a hinge (lmjx arms have hinge joints only)")
        if not m.jnt_limited[j]:
            problems.append(f"joint '{name}' has no position limits (give it a range)")
        if np.any(np.abs(m.jnt_pos[j]) > 1e-12):
            problems.append(
                f"joint '{name}' is off its body's origin (pos {m.jnt_pos[j].round(4).tolist()}): "
                "place the body's frame on the joint axis"
            )
        has_force = m.jnt_actfrclimited[j] and m.jnt_actfrcrange[j][1] > 0
        if not has_force and _numeric_or_none(m, "lmjx_tau_max") is None:
            problems.append(f"joint '{name}' has no torque limit (actuatorfrcrange, or the numeric lmjx_tau_max)")
    bodies_with_joint = {int(m.jnt_bodyid[j]) for j in range(m.njnt)}
    if len(bodies_with_joint) < m.njnt:
        problems.append("a body carries more than one joint (lmjx arms have one hinge per body)")
    for name in ("lmjx_qd_max", "lmjx_qdd_max"):
        v = _numeric_or_none(m, name)
        kind = "velocity" if "qd_max" in name and "qdd" not in name else "acceleration"
        if v is None:
            problems.append(f'no {kind} limits: add <custom><numeric name="{name}" data="..."/> (one per joint)')
        elif len(v) != nq or not np.all(v > 0):
            problems.append(f"the numeric {name} must hold {nq} positive values, one per joint (it holds {len(v)})")
    tau = _numeric_or_none(m, "lmjx_tau_max")
    if tau is not None and (len(tau) != nq or not np.all(tau > 0)):
        problems.append(f"the numeric lmjx_tau_max must hold {nq} positive values, one per joint")
    moving = sorted(_moving_bodies(m))
    collides = {int(m.geom_bodyid[g]) for g in range(m.ngeom) if m.geom_contype[g] or m.geom_conaffinity[g]}
    for b in moving:
        if m.body_mass[b] <= 0:
            problems.append(f"body '{m.body(b).name}' has no mass (give it an <inertial>)")
        if not _subtree_collides(m, b, collides):
            problems.append(f"body '{m.body(b).name}' has no collision geometry")
    for g in range(m.ngeom):
        arm_collider = m.geom_bodyid[g] in moving and (m.geom_contype[g] or m.geom_conaffinity[g])
        if arm_collider and m.geom_type[g] != mujoco.mjtGeom.mjGEOM_CAPSULE:
            gname = m.geom(g).name or f"geom {g}"
            problems.append(f"collision geom '{gname}' of the arm is not a capsule (lmjx checks capsules)")
    try:
        t = m.geom(TABLE_GEOM)
        if t.type[0] != mujoco.mjtGeom.mjGEOM_BOX or m.geom_bodyid[t.id] != 0:
            problems.append("the geom 'table' must be a box fixed to the world")
        elif abs(float(t.pos[2] + t.size[2])) > 1e-9:
            problems.append(f"the table's top must be at z = 0 (it is at {float(t.pos[2] + t.size[2]):g})")
    except KeyError:
        problems.append("no geom named 'table' (a box whose top is the task plane, z = 0)")
    site_names = [m.site(i).name for i in range(m.nsite)]
    for name, what in ((TCP_SITE, "the grasp point"), (FLANGE_SITE, "the centre of the tool flange")):
        if name not in site_names:
            problems.append(f"no site '{name}' ({what})")
    if TCP_SITE in site_names:
        q = m.site_quat[site_names.index(TCP_SITE)]
        if not np.allclose(np.abs(q), [1, 0, 0, 0], atol=1e-9):
            problems.append("the site 'tcp' must not be rotated in its body (the body's z is the approach axis)")
        if m.site_bodyid[site_names.index(TCP_SITE)] not in moving:
            problems.append("the site 'tcp' must sit on the arm")
    if not [n for n in site_names if n.startswith(IP_PREFIX)]:
        problems.append("no interaction-point sites ('ip_<name>', e.g. ip_hand, ip_wrist, ip_forearm)")
    if m.nu != nq or any(m.actuator_trnid[a][0] != a for a in range(min(m.nu, nq))):
        problems.append(f"it needs one position actuator per joint, in joint order ({m.nu} actuators for {nq} joints)")
    return problems


def _numeric_or_none(m: mujoco.MjModel, name: str) -> np.ndarray | None:
    try:
        return np.array(m.numeric(name).data, dtype=np.float64)
    except KeyError:
        return None


def _moving_bodies(m: mujoco.MjModel) -> set[int]:
    """Bodies moved by a joint (theirs or an ancestor's)."""
    out = set()
    for b in range(1, m.nbody):
        a = b
        while a > 0:
            if m.body_jntnum[a] > 0:
                out.add(b)
                break
            a = m.body_parentid[a]
    return out


def _subtree_collides(m: mujoco.MjModel, b: int, collides: set[int]) -> bool:
    """Whether body b, or a body welded to it, has collision geometry."""
    return any(c in collides for c in range(m.nbody) if m.body_weldid[c] == m.body_weldid[b])


def arm_span(m: mujoco.MjModel, tcp_site: int) -> float:
    """The length of the kinematic chain from the first moving body to the grasp point (the
    sum of the body offsets along it): a measure of the arm's size."""
    span = float(np.linalg.norm(m.site_pos[tcp_site]))
    b = int(m.site_bodyid[tcp_site])
    while b > 0 and m.body_parentid[b] > 0:
        span += float(np.linalg.norm(m.body_pos[b]))
        b = int(m.body_parentid[b])
    return span


@functools.lru_cache(maxsize=1)
def _panda_span() -> float:
    m = mujoco.MjModel.from_xml_path(str(MODEL_PATH))
    return arm_span(m, m.site(TCP_SITE).id)


def robots() -> dict[str, str]:
    """The shipped robots: name -> description."""
    return {k: PROFILES[k].description for k in ROBOTS}


def load_robot(name_or_path: str | Path | None = None) -> Robot:
    """Load and cache a robot: a shipped one by name ("panda", the default; "ur5e") or any
    MJCF that meets the contract by its path (RobotError lists what it lacks).  Every way of
    naming one robot (None, "panda", the path of its MJCF) gives the same object, so its
    compiled kernels are shared (threads included: one loads, the others wait for it)."""
    key, path = resolve_robot(name_or_path)
    with _LOADING:
        return _load_robot(key, path)


_LOADING = threading.Lock()


@functools.lru_cache(maxsize=8)
def _load_robot(key: str, path: Path) -> Robot:
    problems = check_robot(path)
    if problems:
        raise RobotError(path, problems)
    text = path.read_bytes()
    m = mujoco.MjModel.from_xml_path(str(path))
    names = tuple(m.joint(j).name for j in range(m.njnt))
    nq = len(names)
    site_names = tuple(m.site(s).name for s in range(m.nsite))
    ips = {n[len(IP_PREFIX) :]: i for i, n in enumerate(site_names) if n.startswith(IP_PREFIX)}
    tau = _numeric_or_none(m, "lmjx_tau_max")
    if tau is None:
        tau = np.array(m.jnt_actfrcrange[:, 1], dtype=np.float64)
    jerk = _numeric_or_none(m, "lmjx_jerk_max")
    phis = [_numeric_or_none(m, f"lmjx_friction_phi{i}") for i in (1, 2, 3)]
    friction = np.stack(phis) if all(x is not None and len(x) == nq for x in phis) else np.zeros((3, nq))
    ready = _numeric_or_none(m, "lmjx_ready")
    profile = PROFILES.get(key) or RobotProfile(
        presets=_text_presets(m),
        task_scale=round(arm_span(m, m.site(TCP_SITE).id) / _panda_span(), 3),
        description=f"{path.name} (a user's robot)",
    )
    return Robot(
        path=path,
        key=key,
        name=ET.fromstring(text).get("model", ""),
        model_hash=hashlib.sha256(text).hexdigest(),
        mj=m,
        arm=_arm_model(m),
        joint_names=names,
        lower=np.array(m.jnt_range[:, 0]),
        upper=np.array(m.jnt_range[:, 1]),
        qd_max=_numeric(m, "lmjx_qd_max"),
        qdd_max=_numeric(m, "lmjx_qdd_max"),
        jerk_max=jerk if jerk is not None and len(jerk) == nq else np.full(nq, np.inf),
        tau_max=tau,
        friction=friction,
        ready=ready if ready is not None and len(ready) == nq else np.zeros(nq),
        inertials=_inertials(m),
        site_names=site_names,
        profile=profile,
        interaction_points=ips,
        tcp_site=site_names.index(TCP_SITE),
        flange_site=site_names.index(FLANGE_SITE),
    )


def _text_presets(m: mujoco.MjModel) -> dict[str, dict[int, float]]:
    """Failure presets a user's MJCF declares: <text name="lmjx_failure_NAME" data="J2=0.3,..."/>."""
    out = {}
    for i in range(m.ntext):
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_TEXT, i) or ""
        if name.startswith(FAILURE_TEXT):
            adr, size = int(m.text_adr[i]), int(m.text_size[i])
            data = bytes(m.text_data[adr : adr + size]).rstrip(b"\0").decode()  # (MjModel has no .text() view)
            locks = {}
            for part in data.split(","):
                j, _, v = part.strip().partition("=")
                locks[int(j.strip().upper().lstrip("J"))] = float(v)
            out[name[len(FAILURE_TEXT) :]] = locks
    return out
