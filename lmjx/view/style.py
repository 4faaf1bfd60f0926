"""The colours of lmjx's pictures, in one place, and the viewer's cameras.

The reach map's labels (PM, NPM, unreachable) have one colour scheme everywhere: `lmjx reach
--png` and the atlas figures (lmjx.reach.plots takes `LABEL_HEX`), the 3D views, the legends
of their pages, README.md and docs/VIEW.md.  It is the Okabe-Ito palette's bluish green and
sky blue, which readers with a colour-vision deficiency tell apart, on a light grey.  The
other things a view shows each have a hue of their own (the arm, the selected cell, the
edges), so that a picture can be read with its legend and checked pixel by pixel; the
scenario's boxes and goal keep the colours the simulator gives them (lmjx.sim.scenarios).
Nothing here draws, except `set_camera`, which sets a server's first view."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lmjx.sim.scenarios import FIXED_RGBA, GOAL_RGBA, OBSTACLE_RGBA, TARGET_RGBA

RGB = tuple[int, int, int]


def hex_rgb(text: str) -> RGB:
    """'#rrggbb' -> (r, g, b), 0-255."""
    return int(text[1:3], 16), int(text[3:5], 16), int(text[5:7], 16)


def rgba_rgb(rgba: tuple[float, ...]) -> RGB:
    """MuJoCo's 0-1 RGBA -> (r, g, b), 0-255."""
    return round(255 * rgba[0]), round(255 * rgba[1]), round(255 * rgba[2])


# The reach map's labels, by their values in the map (lmjx.reach.reachability: 0, 1, 2)
LABEL_HEX = {0: "#d9d9d9", 1: "#56B4E9", 2: "#009E73"}  # unreachable light grey, NPM sky blue, PM bluish green
LABEL_WORDS = {0: "grey", 1: "blue", 2: "green"}
UNREACHABLE: RGB = hex_rgb(LABEL_HEX[0])
NPM: RGB = hex_rgb(LABEL_HEX[1])  # cells reachable by pushing and poking only
PM: RGB = hex_rgb(LABEL_HEX[2])  # cells reachable by a grasp

TABLE: RGB = (88, 88, 96)  # dark grey: everything else stands out on it
ARM: RGB = (240, 128, 40)  # orange: apart from the white boxes, the light grey cells and the yellow target
ARM_DARK: RGB = (60, 60, 64)  # the arm's dark parts (a geom whose own colour is dark, e.g. fingers)
TARGET: RGB = rgba_rgb(TARGET_RGBA)  # yellow
OBSTACLE: RGB = rgba_rgb(OBSTACLE_RGBA)  # white
FIXED: RGB = rgba_rgb(FIXED_RGBA)  # slate grey
GOAL: RGB = rgba_rgb(GOAL_RGBA)  # green, see-through
GOAL_OPACITY = float(GOAL_RGBA[3])
SELECTED: RGB = (220, 30, 40)  # the selected cell (red)
TRANSIT: RGB = (150, 150, 160)  # a trial's transits (grey)
EDGE_PATH: RGB = (40, 200, 230)  # a trial's executed edges (cyan)
PUSH: RGB = (220, 30, 40)  # the target's displacement by an action (red)

CELL_HEIGHT = 0.002  # the cells' tiles [m]: thin, just over the table top
CELL_FILL = 0.86  # a tile's side as a fraction of the cell (the grid stays visible)
PATH_THICKNESS = 3.0  # edges' interaction-point paths [screen pixels]


@dataclass(frozen=True)
class Swatch:
    """One line of a legend: a colour and what it stands for."""

    rgb: RGB
    name: str
    meaning: str
    opacity: float = 1.0

    @property
    def css(self) -> str:
        """The colour as CSS; a see-through one as it shows over the table."""
        a = self.opacity
        r, g, b = (round(a * c + (1 - a) * t) for c, t in zip(self.rgb, TABLE, strict=True))
        return f"rgb({r}, {g}, {b})"


SWATCHES = {
    "pm": Swatch(PM, "PM", "a grasp reaches the cell (prehensile)"),
    "npm": Swatch(NPM, "NPM", "only pushing or poking reaches it (non-prehensile)"),
    "unreachable": Swatch(UNREACHABLE, "unreachable", "no part of the arm reaches it"),
    "arm": Swatch(ARM, "arm", "the robot, its locked joints at their angles"),
    "target": Swatch(TARGET, "target", "the object (a box or a cylinder) to push into the goal"),
    "obstacles": Swatch(OBSTACLE, "obstacles", "movable boxes and cylinders"),
    "fixed": Swatch(FIXED, "fixed", "fixed obstacles"),
    "goal": Swatch(GOAL, "goal", "the region the target must reach", GOAL_OPACITY),
    "selected": Swatch(SELECTED, "selected cell", "the cell whose edges are drawn"),
    "edges": Swatch((128, 128, 255), "edges", "interaction-point paths, cyan (low) to magenta (high)"),
    "transit": Swatch(TRANSIT, "transit", "the way to an edge's start"),
    "edge": Swatch(EDGE_PATH, "edge", "an executed edge"),
    "push": Swatch(PUSH, "push", "the target's displacement by an action"),
    "table": Swatch(TABLE, "table", "the task plane (z = 0)"),
}

# (position, look-at, vertical field of view [rad]) of the first view of a map when its scene
# has no extent to fit (`fit_camera` frames it otherwise), from the robot's front right
MAP_CAMERA = ((1.35, -0.95, 1.2), (0.36, 0.06, 0.12), np.deg2rad(50.0))
# a trial's direction: MuJoCo's view of a trial (lmjx.sim.render.TRIAL_VIEW: azimuth 212 deg,
# elevation -34 deg, 45 deg field of view), from the robot's front left
TRIAL_CAMERA = ((1.415, 0.899, 1.059), (0.36, 0.24, 0.22), np.deg2rad(45.0))
ASPECT = 1.0  # the width over height a fitted view fills (a browser window is wider: a side panel covers part)
MARGIN = 0.08  # the share of the half-height left free around a fitted view
AMBIENT = 1.1  # the ambient light's intensity


def fit_camera(points: np.ndarray, like: tuple, aspect: float = ASPECT, margin: float = MARGIN) -> tuple:
    """A camera (position, look-at, field of view) looking the way `like` looks (its
    direction and field of view), at the middle of `points` (n, 3), as close as it can be
    with every point inside the picture, `margin` of its half-size inside the border (a
    perspective camera of that vertical field of view and `aspect`, z up)."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    pos, look, fov = np.asarray(like[0], float), np.asarray(like[1], float), float(like[2])
    if not len(pts):
        return like
    f = (look - pos) / np.linalg.norm(look - pos)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    centre = (pts.min(axis=0) + pts.max(axis=0)) / 2
    d = pts - centre
    x, y, z = d @ r, d @ u, d @ f
    t = np.tan(fov / 2) * (1.0 - margin)
    # a point at depth z + D (D: the camera's distance to the centre) is inside when
    # |y| <= (z + D) t and |x| <= (z + D) t aspect
    need = np.maximum(np.abs(y) / t, np.abs(x) / (t * aspect)) - z
    distance = max(float(need.max()), 0.05)
    return tuple(float(v) for v in centre - distance * f), tuple(float(v) for v in centre), fov


def colormap(values: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """(n, 3) uint8 colours of `values` from cyan (lo) to magenta (hi), linearly (matplotlib's
    "cool"); lo and hi default to the values' range."""
    v = np.asarray(values, np.float64)
    lo = float(np.nanmin(v)) if lo is None and len(v) else (lo or 0.0)
    hi = float(np.nanmax(v)) if hi is None and len(v) else (hi or 1.0)
    t = np.clip((v - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.full(len(v), 0.5)
    t = np.nan_to_num(t, nan=0.5)
    return (np.stack([t, 1.0 - t, np.ones_like(t)], axis=1) * 255).round().astype(np.uint8)


def set_camera(server, camera: tuple) -> None:
    """The first view of every browser that opens the server (and of an HTML export), and
    the lighting."""
    # no environment map (a preset's HDR picture takes software WebGL many seconds to apply, and
    # viser's default one washes the colours out): an ambient light and viser's directional ones
    server.scene.configure_environment_map(hdri=None)
    server.scene.add_light_ambient("/lights/ambient", intensity=AMBIENT)
    position, look_at, fov = camera
    server.initial_camera.position = position
    server.initial_camera.look_at = look_at
    server.initial_camera.fov = float(fov)
    server.initial_camera.up = (0.0, 0.0, 1.0)
