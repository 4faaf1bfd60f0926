"""Pictures of the evaluation scenarios (`lmjx scenarios`): a MuJoCo rendering of the scene
with the arm at its park pose, beside a top-down diagram of the layout (boxes as rectangles,
cylinders as circles, fixed walls, goal region) in table coordinates.  Without OpenGL only
the diagram is drawn.  Written atomically."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import mujoco
import numpy as np
from matplotlib.patches import Circle, Polygon, Rectangle

from lmjx.model.robot import Robot
from lmjx.runtime.fileio import atomic_path
from lmjx.sim.scenarios import Box, Layout, Scenario, _corners

SCENE_VIEW = dict(lookat=(0.32, 0.18, 0.3), distance=2.1, azimuth=212.0, elevation=-32.0)


def _footprint(b: Box, pose, **style) -> Polygon | Circle:
    """A patch of `b`'s footprint at pose (x, y, yaw): a box's rectangle, a cylinder's circle."""
    if b.shape == "box":
        return Polygon(_corners(b.half, pose[0], pose[1], pose[2], 0.0), closed=True, **style)
    return Circle((pose[0], pose[1]), b.half[0], **style)


def diagram(ax, sc: Scenario, layout: Layout) -> None:
    """Top-down layout: x forward from the robot base, y to its left."""
    gx, gy = sc.goal_center
    hx, hy = sc.goal_half
    ax.add_patch(Rectangle((gx - hx, gy - hy), 2 * hx, 2 * hy, color="#2ca02c", alpha=0.35, label="goal region"))
    for f in sc.fixed:
        roof = f.zc - f.half[2] > 2 * sc.target.half[2]
        style = {"facecolor": "#bbbbbb", "alpha": 0.6, "hatch": "//"} if roof else {"facecolor": "#555566"}
        ax.add_patch(_footprint(f, (f.x, f.y, f.yaw), edgecolor="#333333", label="roof" if roof else "wall", **style))
    for i, (b, p) in enumerate(zip(sc.movable, layout.poses, strict=True)):
        target = i == 0
        ax.add_patch(_footprint(b, p, facecolor="#f2c200" if target else "#e8e8e0", edgecolor="#333333",
                                label="target" if target else ("movable object" if i == 1 else None)))  # fmt: skip
    ax.plot([0], [0], marker="o", color="k", ms=8)
    ax.annotate("robot base", (0, 0), (0.02, -0.05), fontsize=8)
    ax.set_xlim(-0.05, 0.9)
    ax.set_ylim(-0.15, 0.65)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m] (forward)")
    ax.set_ylabel("y [m] (left)")
    ax.grid(alpha=0.3)
    handles, labels = ax.get_legend_handles_labels()
    seen = {}
    for h, lab in zip(handles, labels, strict=True):
        seen.setdefault(lab, h)
    ax.legend(seen.values(), seen.keys(), loc="upper left", fontsize=7)


def render_scene(robot: Robot, sc: Scenario, layout: Layout, q_robot: np.ndarray, width: int = 720,
                 height: int = 540) -> np.ndarray:  # fmt: skip
    from lmjx.sim.render import View, scene_image
    from lmjx.sim.scene import build_scene, object_qpos, set_state

    scene = build_scene(robot, sc)
    d = mujoco.MjData(scene.model)
    set_state(scene, d, q_robot, object_qpos(scene, layout.poses))
    return scene_image(scene, d.qpos, View(**SCENE_VIEW), width, height)


def scenario_picture(robot: Robot, sc: Scenario, layout: Layout, q_robot: np.ndarray, path: str | Path,
                     with_render: bool) -> None:  # fmt: skip
    img = render_scene(robot, sc, layout, q_robot) if with_render else None
    fig = plt.figure(figsize=(12.5 if img is not None else 6, 5.2), constrained_layout=True)
    if img is not None:
        ax0, ax1 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.33, 1]})
        ax0.imshow(img)
        ax0.set_axis_off()
    else:
        ax1 = fig.subplots(1, 1)
    diagram(ax1, sc, layout)
    fig.suptitle(f"Scenario {sc.number}: {sc.title} (layout of seed {layout.seed})", fontsize=11)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
