"""`lmjx view` in a real browser: headless Chromium (Debian's `chromium`) opens the view a
server serves, or the HTML export offline, and takes a screenshot; pixel checks find the
arm, the cells, the edges and the selected cell where the camera puts them (the known 3D
points projected with the view's camera), and a trial's target at its last frame.  Skipped
where Chromium is not installed (test_view.py checks the scene the server sends there)."""

from __future__ import annotations

import colorsys

import h5py
import numpy as np
import pytest
from conftest import cli

viser = pytest.importorskip("viser")

import test_view  # noqa: E402

from lmjx.view import style  # noqa: E402
from lmjx.view.browser import find_chromium, screenshot  # noqa: E402

pytestmark = pytest.mark.skipif(find_chromium() is None, reason="no chromium (Debian: apt install chromium)")

trial_json = test_view.trial_json  # the fixture: a plan's record
SIZE = (1200, 800)
PANEL_X = 850  # the GUI panel covers the window right of this


def project(points: np.ndarray, camera: tuple, size: tuple[int, int] = SIZE) -> np.ndarray:
    """(n, 2) pixel coordinates of world points seen by `camera` (position, look-at, vertical
    field of view; z up), as three.js's perspective camera projects them."""
    pos, look, fov = (np.asarray(camera[0], float), np.asarray(camera[1], float), camera[2])
    f = (look - pos) / np.linalg.norm(look - pos)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    d = np.asarray(points, float) - pos
    x, y, z = d @ r, d @ u, d @ f
    t = np.tan(fov / 2)
    w, h = size
    return np.stack([(x / (z * t * w / h) + 1) / 2 * w, (1 - y / (z * t)) / 2 * h], axis=1)


def hsv(image: np.ndarray) -> np.ndarray:
    """(h, w, 3) hue [deg], saturation, value of an RGB image."""
    flat = image.reshape(-1, 3) / 255.0
    out = np.array([colorsys.rgb_to_hsv(*p) for p in flat])
    out[:, 0] *= 360
    return out.reshape(image.shape)


def fraction_near(image: np.ndarray, pixels: np.ndarray, kind, radius: int = 3) -> float:
    """Of the points `pixels` inside the scene's part of the window, the fraction with a pixel
    of `kind` (a test on h, s, v arrays) within `radius`."""
    inside = [(int(x), int(y)) for x, y in pixels if radius <= x < PANEL_X - radius and radius <= y < SIZE[1] - radius]
    assert inside, "no point falls in the picture"
    hits = 0
    for x, y in inside:
        patch = hsv(image[y - radius : y + radius + 1, x - radius : x + radius + 1])
        hits += bool(kind(patch[..., 0], patch[..., 1], patch[..., 2]).any())
    return hits / len(inside)


def npm(h, s, v):  # the orange NPM tiles (lit: yellow-orange)
    return (h > 25) & (h < 60) & (s > 0.3)


def edge(h, s, v):  # the edges' cyan-to-magenta paths
    return (h > 170) & (h < 320) & (s > 0.12)


def arm(h, s, v):  # the white arm, shaded (not the white page, not the dark table)
    return (s < 0.1) & (v > 0.6) & (v < 0.985)


def selected(h, s, v):
    return ((h < 15) | (h > 345)) & (s > 0.5)


@pytest.fixture
def served():
    """Serve a view in this process: start(view_maker) -> url; stopped after the test."""
    from lmjx.view.server import start_server, stop_server, url_of

    servers = []

    def start(make):
        s = start_server("127.0.0.1", 0, "lmjx")
        servers.append(s)
        make(s)
        return url_of(s).replace("localhost", "127.0.0.1")

    yield start
    for s in servers:
        stop_server(s)


def test_map_with_a_selected_cell_in_chromium(small_map, served, tmp_path, robot):
    from PIL import Image

    from lmjx.planner.clearance import park_pose
    from lmjx.view.map import MapView, MapViewSettings, robot_qpos
    from lmjx.view.mapdata import MapData
    from lmjx.view.shapes import ArmPoser, arm_geoms

    data = MapData(small_map)
    views = []
    url = served(lambda s: views.append(MapView(s, data, MapViewSettings(cap=60))))
    shot = screenshot(url, tmp_path / "map.png", size=SIZE)
    image = np.asarray(Image.open(shot).convert("RGB"))
    sel = views[0].selected

    iy, ix = np.nonzero(data.labels_smooth == 1)
    far = np.hypot(data.xs[ix] - data.xs[sel.ix], data.ys[iy] - data.ys[sel.iy]) > 0.15  # away from the edges
    tiles = np.stack([data.xs[ix], data.ys[iy], np.full(len(ix), style.CELL_HEIGHT)], axis=1)[far]
    assert fraction_near(image, project(tiles, style.MAP_CAMERA), npm, radius=2) > 0.9

    middles = np.array([p[len(p) // 2] for p in sel.p])
    assert fraction_near(image, project(middles, style.MAP_CAMERA), edge) > 0.7

    m = robot.mj
    poser = ArmPoser(m, robot_qpos(robot), arm_geoms(m, {m.body(b).name for b in range(1, m.nbody)}))
    centres, _ = poser.poses(park_pose(robot, data.failure))
    assert fraction_near(image, project(centres, style.MAP_CAMERA), arm) > 0.8

    cell = np.array([[data.xs[sel.ix], data.ys[sel.iy], style.CELL_HEIGHT]])
    assert fraction_near(image, project(cell, style.MAP_CAMERA), selected, radius=4) == 1.0
    # and no tile where the map has none: the unreachable cells two cells or more from a reachable one
    reach = data.labels_smooth >= 1
    near = reach.copy()
    for dy in (-2, -1, 0, 1, 2):
        for dx in (-2, -1, 0, 1, 2):
            near |= np.roll(np.roll(reach, dy, axis=0), dx, axis=1)
    uy, ux = np.nonzero(~near)
    empty = np.stack([data.xs[ux], data.ys[uy], np.full(len(ux), style.CELL_HEIGHT)], axis=1)
    assert len(empty) > 20
    assert fraction_near(image, project(empty, style.MAP_CAMERA), npm, radius=1) < 0.05
    data.close()


def test_trial_at_its_last_frame_in_chromium(trial_json, plan_map, robot, served, tmp_path):
    from PIL import Image

    from lmjx.mapfile.read import load_map
    from lmjx.view.replay import replay
    from lmjx.view.trial import TrialView
    from lmjx.view.trialrecord import read_trial

    with load_map(plan_map, lazy=True) as m:
        rep = replay(robot, m, read_trial(trial_json, None))
    url = served(lambda s: TrialView(s, rep, at=len(rep.frames) - 1))
    image = np.asarray(Image.open(screenshot(url, tmp_path / "trial.png", size=SIZE)).convert("RGB"))

    def target(h, s, v):  # the yellow cube
        return (h > 35) & (h < 65) & (s > 0.5) & (v > 0.4)

    def goal(h, s, v):  # the green goal region
        return (h > 100) & (h < 150) & (s > 0.4)

    sc = rep_scenario(rep)
    end = rep.actions[-1].target_after
    # the cube at its last place: the arm that pushed it there hides part of it from this camera
    assert fraction_near(image, project(end[None], style.TRIAL_CAMERA), target, radius=20) == 1.0
    start = rep.actions[0].target_before
    if np.hypot(*(end - start)[:2]) > 0.08:  # where it stood at first, no cube now
        assert fraction_near(image, project(start[None], style.TRIAL_CAMERA), target, radius=3) == 0.0
    corners = np.array([[sc.goal_center[0] + sx * sc.goal_half[0] * 0.7, sc.goal_center[1] + sy * sc.goal_half[1] * 0.7,
                         0.001] for sx in (-1, 1) for sy in (-1, 1)])  # fmt: skip
    assert fraction_near(image, project(corners, style.TRIAL_CAMERA), goal, radius=6) >= 0.5  # (objects on it)
    # the arm where the last frame has it
    from lmjx.view.map import robot_qpos
    from lmjx.view.shapes import ArmPoser, arm_geoms

    m = robot.mj
    poser = ArmPoser(m, robot_qpos(robot), arm_geoms(m, {m.body(b).name for b in range(1, m.nbody)}))
    centres, _ = poser.poses(rep.frames[-1][rep.robot_qpos])
    assert fraction_near(image, project(centres, style.TRIAL_CAMERA), arm) > 0.7


def rep_scenario(rep):
    from lmjx.model.robot import load_robot
    from lmjx.sim.scenarios import scenario

    r = rep.record
    return scenario(r.scenario, load_robot(r.robot).profile.task_scale, r.tasks)


def test_html_export_opens_offline_in_chromium(small_map, tmp_path):
    from PIL import Image

    out = tmp_path / "map.html"
    cli("view", small_map, "--html", out, "--edges", "30").ok()
    shot = screenshot(out.resolve().as_uri(), tmp_path / "html.png", size=SIZE)  # file://: no server, no network
    image = np.asarray(Image.open(shot).convert("RGB"))
    with h5py.File(small_map, "r") as f:
        xs, ys, lab = f["reach/x"][...], f["reach/y"][...], f["reach/labels_smooth"][...]
    iy, ix = np.nonzero(lab == 1)
    tiles = np.stack([xs[ix], ys[iy], np.full(len(ix), style.CELL_HEIGHT)], axis=1)
    assert fraction_near(image, project(tiles, style.MAP_CAMERA), npm, radius=2) > 0.6
