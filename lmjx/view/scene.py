"""The scene view: a scene file (or any task) before planning: the table, the target and the
movable objects (boxes, cylinders) at their nominal poses, the fixed obstacles and the goal
region (`lmjx.view.world`), the arm (in its failure's park pose with a map, else in its ready
pose), and, with a map, its reach cells under them (PM, NPM, unreachable:
`lmjx.view.map.draw_cells`), so that a user sees where the goal and the objects lie against
what the arm reaches.  Nothing is simulated."""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from lmjx.model.robot import Robot
from lmjx.reach.reachability import ReachResult
from lmjx.sim.scenarios import Task
from lmjx.view import style
from lmjx.view.legend import Page, add_legend
from lmjx.view.map import cells_extent, draw_cells
from lmjx.view.trial import extent_points
from lmjx.view.world import draw_world

ROOT = "/scene"
# the scene's direction: the trial's (from the robot's front left)
SCENE_CAMERA = style.TRIAL_CAMERA


def _count(n: int, what: str, plural: str = "s") -> str:
    return f"{n} {what}" + ("" if n == 1 else plural)


class SceneView:
    """Draws `task` for `robot` (with `reach`: its cells; `q`: the arm's pose) into a viser
    server's scene, with its title and legend.  Every scene node lives under /scene."""

    def __init__(
        self,
        server: Any,
        task: Task,
        robot: Robot,
        q: np.ndarray,
        reach: ReachResult | None = None,
        source: str = "",
        failure: str = "",
    ) -> None:
        from lmjx.sim.scene import build_scene, object_qpos, set_state

        self.server = server
        self.task = task
        sc = task.scenario
        scene = build_scene(robot, sc)
        self.model = scene.model
        d = mujoco.MjData(scene.model)
        poses = np.array([[b.x, b.y, b.yaw] for b in sc.movable])
        set_state(scene, d, q, object_qpos(scene, poses))
        self.qpos = d.qpos.copy()
        extent = extent_points(scene.model, self.qpos[None], sc)
        if reach is not None:
            self.cells = draw_cells(server, f"{ROOT}/cells", reach.xs, reach.ys, reach.labels_smooth, reach.config.cell)
            extent = np.concatenate([extent, cells_extent(reach.xs, reach.ys, reach.config.cell)])
        self.camera = style.fit_camera(extent, SCENE_CAMERA)
        style.set_camera(server, self.camera)
        self.drawn = draw_world(server, ROOT, scene.model, d, sc)
        pose = f"the arm in failure {failure}'s park pose" if failure else "the arm in its ready pose"
        cells = "; the map's reach cells (smoothed labels) under them" if reach is not None else ""
        movable = ("movable box", "es") if all(b.shape == "box" for b in sc.obstacles) else ("movable object", "s")
        sizes = (f"the target, {_count(len(sc.obstacles), *movable)} at their nominal poses, "
                 f"{_count(len(sc.fixed), 'fixed obstacle')}")  # fmt: skip
        lines = tuple(x for x in (sc.description, f"{sizes}; budget {sc.budget} actions; {pose}{cells}.", source) if x)
        legend = ("pm", "npm", "unreachable") if reach is not None else ()
        legend += tuple(k for k in ("arm", "target", "obstacles", "fixed", "goal", "table") if k in self.drawn.parts)
        self.page = Page(f"Scene {task.name}" + (f": {sc.title}" if sc.title != task.name else ""), lines, legend)
        server.gui.add_markdown(f"**{self.page.title}**  \n" + "  \n".join(self.page.lines))
        add_legend(server, self.page)
