"""The failure atlas as a page and a figure: per set of locked joints, the distribution of
PM and NPM+PM areas over its lock angles, and the failures NPM rescues (PM area 0, NPM+PM
area above 0).  Written atomically."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from lmjx.reach.atlas import AtlasState, plane_area, summarize
from lmjx.reach.plots import COLORS
from lmjx.reach.reachability import NPM, PM
from lmjx.runtime.fileio import atomic_path, write_text_atomic


def atlas_figure(st: AtlasState, path: str | Path) -> None:
    """One row per joint subset: every map's NPM+PM area (blue) and PM area (green)."""
    rows = summarize(st)
    areas = st.areas()
    keys = ["+".join(f"J{j}" for j in row if j > 0) for row in st.joints]
    fig, ax = plt.subplots(figsize=(9, 0.19 * len(rows) + 1.6), constrained_layout=True)
    for y, r in enumerate(rows):
        idx = [i for i, k in enumerate(keys) if k == r["locked"] and st.done[i]]
        jitter = (np.arange(len(idx)) % 5 - 2) * 0.06
        ax.scatter(areas["npm_pm"][idx], y + jitter, s=10, color=COLORS[NPM], label="NPM+PM" if y == 0 else None)
        ax.scatter(areas["pm"][idx], y + jitter, s=10, marker="s", color=COLORS[PM], label="PM" if y == 0 else None)
        if r["rescued_by_npm"]:
            ax.text(plane_area(st) * 1.01, y, f"{len(r['rescued_by_npm'])} rescued", va="center", fontsize=7)
    ax.set_yticks(range(len(rows)), [r["locked"] for r in rows], fontsize=7)
    ax.invert_yaxis()
    ax.set_xlim(0, plane_area(st) * 1.12)
    ax.set_xlabel("area of the task plane [m²]")
    ax.grid(axis="x", alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(f"Failure atlas: {st.n} maps, K = {st.config.angles} lock angles per locked joint", fontsize=10)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=130, format="png")
    plt.close(fig)


def atlas_markdown(st: AtlasState, figure: str | None, intro: str = "") -> str:
    rows = summarize(st)
    areas = st.areas()
    n_done = int(st.done.sum())
    pm0 = int(((areas["pm"] == 0) & st.done).sum())
    rescued = int(((areas["pm"] == 0) & (areas["npm_pm"] > 0) & st.done).sum())
    dead = int(((areas["npm_pm"] == 0) & st.done).sum())
    out = [
        "# Failure atlas",
        "",
        intro,
        f"{n_done} maps of {st.n}; task plane {plane_area(st):.2f} m² in cells of {st.config.reach.cell * 100:g} cm; "
        f"seed {st.config.seed}.  PM = 0 in {pm0} maps; NPM rescues {rescued} of them (NPM+PM > 0); "
        f"{dead} leave the arm nothing at all.",
        "",
    ]
    if figure:
        out += [f"![atlas]({figure})", ""]
    out += [
        "| locked | maps | PM m² min / median / max | NPM+PM m² min / median / max | PM = 0 | rescued by NPM "
        "| unusable |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        p, q = r["pm_m2"], r["npm_pm_m2"]
        out.append(
            f"| {r['locked']} | {r['maps']} | {p['min']:.3f} / {p['median']:.3f} / {p['max']:.3f} | "
            f"{q['min']:.3f} / {q['median']:.3f} / {q['max']:.3f} | {r['pm_zero']} | {len(r['rescued_by_npm'])} | "
            f"{r['unusable']} |"
        )
    res = [(r["locked"], s) for r in rows for s in r["rescued_by_npm"]]
    if res:
        out += ["", "## Failures NPM turns from unusable into usable", ""]
        out += [f"- `{s}`: NPM+PM {areas['npm_pm'][_index(st, s)]:.3f} m²" for _, s in res]
    return "\n".join(out) + "\n"


def _index(st: AtlasState, spec: str) -> int:
    return next(i for i in range(st.n) if st.spec(i) == spec)


def write_summary(st: AtlasState, md_path: str | Path, png_path: str | Path, intro: str = "") -> None:
    md_path, png_path = Path(md_path), Path(png_path)
    atlas_figure(st, png_path)
    try:
        rel = str(png_path.resolve().relative_to(md_path.resolve().parent))
    except ValueError:
        rel = str(png_path.resolve())
    write_text_atomic(md_path, atlas_markdown(st, rel, intro))
