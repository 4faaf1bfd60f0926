"""The MJCF `lmjx robot import` writes: bodies with their fitted capsules, sites (flange, tcp,
interaction points by `IP_RULES`), a stand-in gripper for a bare arm (`GRIPPERS`), failure
presets, self-collision exclusions, the table and the actuators, as docs/ROBOTS.md asks.
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass

import mujoco
import numpy as np

from lmjx.model.capsule_fit import Capsule, segment_distance
from lmjx.model.import_source import ImportOptions, SourceError, _numbers, _parse_link_point

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
    # the shipped UR5e's gripper (lmjx/model/assets/ur5e.xml): a Robotiq 2F-85 opened to 85 mm
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
        "Collision capsules (lmjx.model.capsule_fit: every vertex enclosed; the union's volume over the",
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
