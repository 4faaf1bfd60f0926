"""Which arms survive joint locks: the failure atlases of several arms side by side
(`lmjx atlas --compare`, docs/ARMS.md).

Per arm, from its atlas file (every 2- and 3-joint lock at K angles per locked joint) and
its no-failure Reach-Ability map computed with the atlas's own map parameters: the
no-failure PM and NPM+PM areas; the share of locks that leave no grasp (PM = 0); the share
that NPM makes usable again (PM = 0 but NPM+PM > 0); the share that leaves nothing; and the
median area kept (a lock's area over the no-failure area), over all locks and per number
of locked joints.  Areas are after hole filling, as everywhere in lmjx.

The figures are pure functions of the atlases (`arm_survival`); the CLI computes the
no-failure maps and writes the page.  The generated part of the page sits between two
markers, so that the prose around it survives a regeneration.  This module computes no
atlas.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from lmjx.errors import ConfigError
from lmjx.reach.atlas import AtlasState, plane_area
from lmjx.reach.plots import COLORS
from lmjx.reach.reachability import NPM, PM, UNREACHABLE
from lmjx.runtime.fileio import atomic_path, write_text_atomic

BEGIN = "<!-- lmjx atlas --compare: begin (generated; edit outside the markers) -->"
END = "<!-- lmjx atlas --compare: end -->"


@dataclass(frozen=True)
class Outcomes:
    """Lock outcomes of one arm over a set of locks (all, or those of s locked joints)."""

    locks: int
    pm_zero: int  # PM = 0: no grasp left
    rescued: int  # PM = 0 and NPM+PM > 0: NPM makes the arm usable again
    dead: int  # NPM+PM = 0: nothing left
    median_pm_kept: float  # median over locks of PM / no-failure PM
    median_npm_pm_kept: float  # median over locks of NPM+PM / no-failure NPM+PM

    def share(self, count: int) -> float:
        return count / self.locks if self.locks else float("nan")


@dataclass(frozen=True, eq=False)
class ArmSurvival:
    robot: str  # the name the atlas records
    joints: int
    angles: int  # K
    cell: float  # [m]
    plane: float  # task plane [m^2] (scaled by the arm's size)
    none_pm: float  # no-failure areas [m^2]
    none_npm_pm: float
    all: Outcomes
    by_size: dict[int, Outcomes]  # locked joints -> outcomes
    npm_pm_kept: np.ndarray  # (N,) every lock's NPM+PM area over the no-failure one


def _outcomes(pm: np.ndarray, npm: np.ndarray, none_pm: float, none_npm: float) -> Outcomes:
    return Outcomes(
        locks=len(pm),
        pm_zero=int((pm == 0).sum()),
        rescued=int(((pm == 0) & (npm > 0)).sum()),
        dead=int((npm == 0).sum()),
        median_pm_kept=float(np.median(pm) / none_pm) if none_pm > 0 and len(pm) else float("nan"),
        median_npm_pm_kept=float(np.median(npm) / none_npm) if none_npm > 0 and len(npm) else float("nan"),
    )


def arm_survival(st: AtlasState, none_areas: dict[str, float], joints: int) -> ArmSurvival:
    """The figures of one arm from its atlas and its no-failure areas {"pm", "npm_pm"} [m^2]."""
    if not st.done.all():
        raise ConfigError(f"the atlas of {st.robot} is incomplete ({int(st.done.sum())} of {st.n} maps)")
    areas = st.areas()
    pm, npm = areas["pm"], areas["npm_pm"]
    size = (st.joints > 0).sum(axis=1)
    n_pm, n_npm = float(none_areas["pm"]), float(none_areas["npm_pm"])
    return ArmSurvival(
        robot=st.robot,
        joints=joints,
        angles=st.config.angles,
        cell=st.config.reach.cell,
        plane=plane_area(st),
        none_pm=n_pm,
        none_npm_pm=n_npm,
        all=_outcomes(pm, npm, n_pm, n_npm),
        by_size={int(s): _outcomes(pm[size == s], npm[size == s], n_pm, n_npm) for s in sorted(set(size.tolist()))},
        npm_pm_kept=npm / n_npm if n_npm > 0 else np.full(len(npm), np.nan),
    )


def _pct(o: Outcomes, count: int) -> str:
    return f"{count} ({100 * o.share(count):.0f} %)"


def compare_markdown(arms: list[ArmSurvival], missing: dict[str, str], figure: str | None) -> str:
    """The generated block of docs/ARMS.md: the tables, the figure, the missing atlases."""
    out = [BEGIN, ""]
    if arms:
        a0 = arms[0]
        out += [
            f"Every lock of {' and '.join(str(k) for k in a0.by_size)} joints at K = {a0.angles} lock angles per "
            "locked joint (the atlases); areas after "
            f"hole filling in cells of {a0.cell * 100:g} cm; kept: a lock's area over the arm's own no-failure area "
            "(each arm's task plane is scaled by its size, so compare shares, not square metres).",
            "",
            "| arm | joints | no failure PM / NPM+PM [m²] | locks | no grasp (PM = 0) | usable again by NPM "
            "| nothing left | median kept PM / NPM+PM |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
        ]
        for a in arms:
            o = a.all
            out.append(
                f"| {a.robot} | {a.joints} | {a.none_pm:.3f} / {a.none_npm_pm:.3f} | {o.locks} | "
                f"{_pct(o, o.pm_zero)} | {_pct(o, o.rescued)} | {_pct(o, o.dead)} | "
                f"{100 * o.median_pm_kept:.0f} % / {100 * o.median_npm_pm_kept:.0f} % |"
            )
        out += [
            "",
            "By the number of locked joints:",
            "",
            "| arm | locked | locks | no grasp | usable again by NPM | nothing left | median kept PM / NPM+PM |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
        ]
        for a in arms:
            for s, o in a.by_size.items():
                out.append(
                    f"| {a.robot} | {s} | {o.locks} | {_pct(o, o.pm_zero)} | {_pct(o, o.rescued)} | "
                    f"{_pct(o, o.dead)} | {100 * o.median_pm_kept:.0f} % / {100 * o.median_npm_pm_kept:.0f} % |"
                )
        if figure:
            out += ["", f"![arms]({figure})"]
    if missing:
        out += [""] if out[-1] else []
        out += ["Atlases missing (the arm's row comes when its atlas exists):", ""]
        out += [f"- {k}: {v}" for k, v in missing.items()]
    out += ["", END]
    return "\n".join(out) + "\n"


def compare_figure(arms: list[ArmSurvival], path: str | Path) -> None:
    """Left: each arm's locks by outcome (grasp kept, usable again by NPM, nothing left).
    Right: the NPM+PM area kept over its locks (box: quartiles; whiskers: 5-95 %)."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 0.5 * len(arms) + 1.8), constrained_layout=True)
    names = [a.robot for a in arms]
    y = np.arange(len(arms))
    kept = np.array([a.all.share(a.all.locks - a.all.pm_zero) for a in arms])
    resc = np.array([a.all.share(a.all.rescued) for a in arms])
    dead = np.array([a.all.share(a.all.dead) for a in arms])
    ax1.barh(y, kept, color=COLORS[PM], label="grasp kept (PM > 0)")
    ax1.barh(y, resc, left=kept, color=COLORS[NPM], label="usable again by NPM")
    ax1.barh(y, dead, left=kept + resc, color=COLORS[UNREACHABLE], label="nothing left")
    ax1.set_yticks(y, names)
    ax1.invert_yaxis()
    ax1.set_xlim(0, 1)
    ax1.set_xlabel("share of the locks")
    ax1.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=3, fontsize=7, frameon=False)
    ax2.boxplot(
        [a.npm_pm_kept for a in arms], orientation="horizontal", positions=y, whis=(5, 95), showfliers=False, widths=0.5
    )
    ax2.set_yticks(y, names)
    ax2.invert_yaxis()
    ax2.set_xlim(0, 1.05)
    ax2.set_xlabel("NPM+PM area kept (over no failure)")
    ax2.grid(axis="x", alpha=0.3)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=130, format="png")
    plt.close(fig)


def write_page(md_path: str | Path, arms: list[ArmSurvival], missing: dict[str, str]) -> Path | None:
    """Write the figure (img/<page>.png beside the page: docs/img/arms.png for docs/ARMS.md) and the
    generated block into the page: between the markers if the page has them, else the whole
    page.  Returns the figure's path (None without arms)."""
    md = Path(md_path)
    png = None
    rel = None
    if arms:
        png = md.parent / "img" / f"{md.stem.lower()}.png"
        compare_figure(arms, png)
        rel = str(png.relative_to(md.parent))
    block = compare_markdown(arms, missing, rel)
    old = md.read_text(encoding="utf-8") if md.exists() else ""
    if BEGIN in old and END in old:
        head, _, rest = old.partition(BEGIN)
        _, _, tail = rest.partition(END)
        text = head + block.rstrip("\n") + tail
    else:
        text = "# Which arms survive joint locks\n\n" + block
    write_text_atomic(md, text)
    return png


def compare_atlases(specs: list[str], out: str | Path | None) -> tuple[list[ArmSurvival], dict[str, str]]:
    """`lmjx atlas --compare ROBOT[=ATLAS]` (repeatable): ROBOT a shipped name or an MJCF path,
    ATLAS its atlas file (default: the robot's maps folder's atlas.h5).  Each arm's no-failure
    map is computed with its atlas's parameters.  Returns the arms and the missing atlases."""
    from dataclasses import replace

    from lmjx.model.robot import load_robot
    from lmjx.reach.atlas import read_atlas
    from lmjx.reach.reachability import reach_map

    arms, missing = [], {}
    for spec in specs:
        name, _, path = spec.partition("=")
        robot = load_robot(name)
        atlas = Path(path or f"{robot.maps_dir}/atlas.h5")
        if not atlas.exists():
            missing[name] = f"no atlas at `{atlas}` (`lmjx atlas --robot {name} --out {atlas}`)"
            continue
        st = read_atlas(atlas, robot)
        if st.robot_hash != robot.model_hash:
            raise ConfigError(f"{atlas} was computed for another version of {name}'s model; recompute it")
        none = reach_map("none", replace(st.config.reach, traced_locks=False), robot=robot).areas()
        arms.append(arm_survival(st, none, robot.nq))
    if out is not None:
        write_page(out, arms, missing)
    return arms, missing


def compare_report(specs: list[str], out: str | Path | None) -> tuple[dict, list[str]]:
    """`lmjx atlas --compare`: (the JSON summary, the lines printed)."""
    arms, missing = compare_atlases(specs, out)
    rows = [
        {"robot": a.robot, "joints": a.joints, "none_m2": {"pm": a.none_pm, "npm_pm": a.none_npm_pm},
         "locks": a.all.locks, "pm_zero": a.all.pm_zero, "rescued_by_npm": a.all.rescued, "unusable": a.all.dead,
         "median_kept": {"pm": a.all.median_pm_kept, "npm_pm": a.all.median_npm_pm_kept}}
        for a in arms
    ]  # fmt: skip
    lines = [
        f"{r['robot']}: no failure PM {r['none_m2']['pm']:.3f}, NPM+PM {r['none_m2']['npm_pm']:.3f} m^2; "
        f"{r['locks']} locks: PM = 0 in {r['pm_zero']}, NPM rescues {r['rescued_by_npm']}, nothing left in "
        f"{r['unusable']}; median kept PM {100 * r['median_kept']['pm']:.0f} %, NPM+PM "
        f"{100 * r['median_kept']['npm_pm']:.0f} %"
        for r in rows
    ]
    lines += [f"missing: {k}: {v}" for k, v in missing.items()]
    if out is not None:
        lines.append(f"written to {out}")
    return {"arms": rows, "missing": missing}, lines
