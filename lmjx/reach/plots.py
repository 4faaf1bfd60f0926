"""Figures: the Reach-Ability heatmap (raw and smoothed side by side) and the lock-search
grid.  Matplotlib with the Agg backend, in the format the caller names (the command line
takes it from the file's extension); files are written atomically."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import ListedColormap
from matplotlib.patches import Patch

from lmjx.reach.reachability import NPM, PM, UNREACHABLE, ReachResult
from lmjx.runtime.fileio import atomic_path
from lmjx.view.style import LABEL_HEX

COLORS = {level: LABEL_HEX[level] for level in (UNREACHABLE, NPM, PM)}  # the one scheme of every picture


def reach_heatmap(result: ReachResult, path: str | Path, fmt: str = "png") -> None:
    """Write a figure (`fmt`: a matplotlib format, png by default) of the raw and smoothed
    labels over the table, robot base marked."""
    cmap = ListedColormap([COLORS[UNREACHABLE], COLORS[NPM], COLORS[PM]])
    cell = result.config.cell
    x0, x1 = result.xs[0] - cell / 2, result.xs[-1] + cell / 2
    y0, y1 = result.ys[0] - cell / 2, result.ys[-1] + cell / 2
    fig, axes = plt.subplots(1, 2, figsize=(11, 5.6), constrained_layout=True)
    for ax, labels, title, smooth in (
        (axes[0], result.labels, "raw", False),
        (axes[1], result.labels_smooth, "smoothed", True),
    ):
        # x (forward) up the page, y (left) to the left, as seen from above the robot.
        ax.imshow(
            labels.T[::-1, ::-1],
            cmap=cmap,
            vmin=0,
            vmax=2,
            extent=(y1, y0, x0, x1),
            interpolation="nearest",
        )
        ax.set_xlim(max(y1, 0.1) + 0.05, min(y0, -0.1) - 0.05)
        ax.set_ylim(min(x0, 0.0) - 0.12, x1 + 0.03)
        ax.plot([0], [0], marker="o", ms=14, mfc="#444444", mec="black")
        ax.annotate("robot base", (0, 0), xytext=(0, -0.085), ha="center", fontsize=8, textcoords="data")
        a = result.areas(smooth=smooth)
        ax.set_title(f"{title}: PM {a['pm']:.3f} m², NPM+PM {a['npm_pm']:.3f} m²", fontsize=10)
        ax.set_xlabel("y [m] (robot's left is left)")
        ax.set_ylabel("x [m] (forward)")
        ax.set_aspect("equal")
        ax.grid(alpha=0.25)
    handles = [
        Patch(color=COLORS[v], label=lab)
        for v, lab in ((PM, "PM (grasp)"), (NPM, "NPM only (push/poke)"), (UNREACHABLE, "unreachable"))
    ]
    fig.legend(handles=handles, loc="lower center", ncol=3, bbox_to_anchor=(0.5, -0.06), frameon=False)
    fig.suptitle(f"Reach-Ability map, failure {result.failure.describe()}, {cell * 100:g} cm cells")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight", format=fmt)
    plt.close(fig)


def lock_search_plot(
    grid_a: np.ndarray,
    grid_b: np.ndarray,
    pm: np.ndarray,
    npm_pm: np.ndarray,
    names: tuple[str, str],
    chosen: tuple[float, float] | None,
    path: str | Path,
    fmt: str = "png",
) -> None:
    """Heatmaps of PM and NPM+PM area over a 2-D grid of lock angles (`fmt`: a matplotlib format)."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), constrained_layout=True)
    for ax, data, title in ((axes[0], pm, "PM area [m²]"), (axes[1], npm_pm, "NPM+PM area [m²]")):
        im = ax.imshow(
            data,
            origin="lower",
            aspect="auto",
            cmap="viridis",
            vmin=0,
            vmax=max(1e-9, float(np.nanmax(npm_pm))),
        )
        ax.set_xticks(range(len(grid_b)), [f"{v:.2f}" for v in grid_b], rotation=60, fontsize=8)
        ax.set_yticks(range(len(grid_a)), [f"{v:.2f}" for v in grid_a], fontsize=8)
        ax.set_xlabel(f"{names[1]} lock angle [rad]")
        ax.set_ylabel(f"{names[0]} lock angle [rad]")
        for i in range(data.shape[0]):
            for j in range(data.shape[1]):
                bright = data[i, j] > 0.6 * float(np.nanmax(npm_pm))
                color = "black" if bright else "white"
                ax.text(j, i, f"{data[i, j]:.2f}", ha="center", va="center", fontsize=6, color=color)
        if chosen is not None:
            i = int(np.argmin(np.abs(grid_a - chosen[0])))
            j = int(np.argmin(np.abs(grid_b - chosen[1])))
            ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, ec="red", lw=2))
        ax.set_title(title)
        fig.colorbar(im, ax=ax, shrink=0.8)
    fig.suptitle(f"Lock search over ({names[0]}, {names[1]}); red: the chosen lock")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format=fmt)
    plt.close(fig)
