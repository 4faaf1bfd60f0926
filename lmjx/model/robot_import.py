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
    primitives' surfaces) is enclosed by 1-3 capsules (`lmjx.model.capsule_fit`); the share of
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

import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from lmjx.model.capsule_fit import Capsule, coverage, fit_capsules, union_volume
from lmjx.model.import_source import (
    ImportOptions,
    SourceError,
    _children,
    _collision_points,
    _limits,
    _parse_link_point,
    arm_chain,
    load_source,
)
from lmjx.model.import_write import (
    GRIPPER_BODY,
    Frame,
    _header,
    _interaction_points,
    _joint_values,
    _parse_gripper,
    _presets,
    _quat,
    _touching_pairs,
    _write_mjcf,
)
from lmjx.runtime.fileio import write_text_atomic


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
class ImportReport:
    out: Path
    joints: list[str]
    fits: list[LinkFit]
    welded: list[str]
    excluded: list[tuple[str, str]]
    notes: list[str]


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


def command_line() -> str:
    return "lmjx " + " ".join(shlex.quote(a) for a in sys.argv[1:])
