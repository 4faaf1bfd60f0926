"""A scenario's MuJoCo scene drawn into a viser scene: the table, the fixed obstacles, the
goal region, the target and the movable boxes and cylinders, and the arm, each geom in the colour of its
part (`lmjx.view.style`: the arm's own, the boxes' and the goal's as the simulator gives
them), with labels naming the target, the goal and the fixed obstacles; the bodies that
move get frames of their own, which the trial view moves.  Shared by the trial view and the
scene view; nothing here replays or plans."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from lmjx.sim.scenarios import Scenario
from lmjx.view import style
from lmjx.view.shapes import geom_mesh, geom_rgb, mat_to_wxyz, shown_geoms

LABEL_LIFT = 0.06  # [m] a label above what it names
GOAL_LIFT = style.CELL_HEIGHT + 0.001  # [m] the goal region drawn over the reach cells (a view may show both)
GOAL_LINE = 3.0  # the goal region's outline [screen pixels]


def geom_part(m: mujoco.MjModel, g: int, sc: Scenario) -> str:
    """What geom g of a scene (`lmjx.sim.scene.build_scene`) is part of: "table", "goal",
    "target", "obstacles", "fixed" or "arm" (a key of `style.SWATCHES`)."""
    name, body = m.geom(g).name, m.body(int(m.geom_bodyid[g])).name
    if name in ("table", "goal"):
        return name
    if body == sc.target.name:
        return "target"
    if body in {b.name for b in sc.obstacles}:
        return "obstacles"
    if name in {b.name for b in sc.fixed}:
        return "fixed"
    return "arm"


def part_rgb(m: mujoco.MjModel, g: int, part: str) -> tuple[style.RGB, float]:
    """Geom g's colour and opacity: the arm's (its dark parts dark), the table's, the goal's;
    the boxes keep their own (a scene file may colour them)."""
    own = geom_rgb(m, g)
    if part == "arm":
        return (style.ARM if max(own) > 128 else style.ARM_DARK), 1.0
    if part == "table":
        return style.TABLE, 1.0
    if part == "goal":
        return style.GOAL, style.GOAL_OPACITY
    return own, 1.0


def moving_bodies(m: mujoco.MjModel) -> list[int]:
    """The bodies that move: on a joint, or welded to one that is."""
    return [b for b in range(1, m.nbody) if m.body_weldid[b] != 0 or m.body_jntnum[b] > 0]


@dataclass
class DrawnWorld:
    """What `draw_world` added: a frame per moving body (set its position and wxyz to move it)
    and the parts it drew."""

    frames: dict[int, Any]
    parts: set[str]


def draw_world(server: Any, root: str, m: mujoco.MjModel, d: mujoco.MjData, sc: Scenario) -> DrawnWorld:
    """Draw scene `m` at state `d` (after `mj_kinematics`) under `root`: the static geoms
    where they are, the moving ones in their bodies' frames (`root`/bodies/NAME)."""
    scene = server.scene
    moving = moving_bodies(m)
    frames = {b: scene.add_frame(f"{root}/bodies/{m.body(b).name}", show_axes=False) for b in moving}
    for b, handle in frames.items():
        handle.position, handle.wxyz = d.xpos[b].copy(), d.xquat[b].copy()
    parts: set[str] = set()
    for g in shown_geoms(m, range(m.ngeom)):
        g = int(g)
        mesh = geom_mesh(m, g)
        assert mesh is not None
        b = int(m.geom_bodyid[g])
        part = geom_part(m, g, sc)
        parts.add(part)
        rgb, opacity = part_rgb(m, g, part)
        name = m.geom(g).name or f"geom{g}"
        extra = {"opacity": opacity} if opacity < 1.0 else {}
        if b in frames:  # placed in its body's frame, which moves
            scene.add_mesh_simple(f"{root}/bodies/{m.body(b).name}/{name}", mesh.vertices, mesh.faces, color=rgb,
                                  position=m.geom_pos[g], wxyz=m.geom_quat[g], **extra)  # fmt: skip
        else:
            at = d.geom_xpos[g] + np.array([0.0, 0.0, GOAL_LIFT if part == "goal" else 0.0])
            scene.add_mesh_simple(f"{root}/static/{name}", mesh.vertices, mesh.faces, color=rgb, position=at,
                                  wxyz=mat_to_wxyz(d.geom_xmat[g]), **extra)  # fmt: skip
    _goal_outline(server, root, sc)
    _labels(server, root, m, d, sc, frames)
    return DrawnWorld(frames, parts)


def _goal_outline(server: Any, root: str, sc: Scenario) -> None:
    """The goal region's border, in its colour, over everything on the table top."""
    (gx, gy), (hx, hy) = sc.goal_center, sc.goal_half
    z = GOAL_LIFT + 0.001
    c = [(gx - hx, gy - hy, z), (gx + hx, gy - hy, z), (gx + hx, gy + hy, z), (gx - hx, gy + hy, z)]
    pts = np.array([[c[k], c[(k + 1) % 4]] for k in range(4)], np.float32)
    server.scene.add_line_segments(f"{root}/static/goal_outline", pts, colors=style.GOAL, thickness=GOAL_LINE,
                                   thickness_units="screen")  # fmt: skip


def _labels(server: Any, root: str, m: mujoco.MjModel, d: mujoco.MjData, sc: Scenario, frames: dict) -> None:
    """Names over the target (moving with it), the goal region and each fixed obstacle."""
    scene = server.scene
    target = m.body(sc.target.name).id
    lift = np.array([0.0, 0.0, sc.target.half[2] + LABEL_LIFT])
    if target in frames:
        scene.add_label(f"{root}/bodies/{sc.target.name}/label", "target", position=tuple(lift), anchor="bottom-center")
    goal = (*sc.goal_center, 0.01)
    scene.add_label(f"{root}/labels/goal", "goal", position=goal, anchor="top-center")
    for b in sc.fixed:
        top = (b.x, b.y, b.zc + b.half[2] + 0.02)
        scene.add_label(f"{root}/labels/{b.name}", f"{b.name} (fixed)", position=top, anchor="bottom-center")
