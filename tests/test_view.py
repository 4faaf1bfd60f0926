"""`lmjx view`: the scene the viewer's server sends (decoded from viser's scene recording, as a
browser receives it) checked against the map file read with plain h5py and against C MuJoCo;
lazy reading; every input `view` takes, made by the commands that write it (a map from
lmjx build-map, a scene file, lmjx plan --json of a shipped scenario and of a scene file,
lmjx evaluate's results.json by folder and by file, and the same records without what older
records lack); the trial's task from its record's scene; the HTML export's title and legend;
the one colour scheme; the cameras; an MJCF's meshes; one-line errors.  What a browser draws
of it is tested in test_view_browser.py (where Chromium is installed)."""

from __future__ import annotations

import base64
import json
import re
import socket
import sys
from pathlib import Path
from types import SimpleNamespace

import h5py
import mujoco
import numpy as np
import pytest
from conftest import cli

viser = pytest.importorskip("viser")

from lmjx.view import style  # noqa: E402
from lmjx.view.recording import decode_recording, latest_nodes  # noqa: E402


@pytest.fixture
def server():
    from lmjx.view.server import start_server, stop_server

    s = start_server("127.0.0.1", 0, "lmjx test")
    yield s
    stop_server(s)


def nodes_of(server) -> dict:
    return latest_nodes(decode_recording(server.get_scene_serializer().serialize())[1])


def plain_cell_edges(path, iy: int, ix: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """The edges over a cell and their interaction points, read as maps/README.md says."""
    with h5py.File(path, "r") as f:
        e = f["edges"]
        nx = int(e["index"].attrs["nx"])
        offset = e["index/offset"][...]
        c = iy * nx + ix
        ids = e["index/edges"][offset[c] : offset[c + 1]]
        first, length = e["offset"][...], e["length"][...]
        return ids, [e["p"][first[k] : first[k] + length[k]] for k in ids]


def test_map_scene_matches_the_file(small_map, server, robot):
    from lmjx.planner.clearance import park_pose
    from lmjx.view.map import MapView, MapViewSettings
    from lmjx.view.mapdata import MapData

    with h5py.File(small_map, "r") as f:
        xs, ys, labels = f["reach/x"][...], f["reach/y"][...], f["reach/labels_smooth"][...]
        counts = np.diff(f["edges/index/offset"][...]).reshape(len(ys), len(xs))
    iy, ix = (int(v) for v in np.unravel_index(int(np.argmax(counts)), counts.shape))
    with MapData(small_map) as data:
        view = MapView(server, data, MapViewSettings(cap=40))
        assert (view.selected.iy, view.selected.ix) == (iy, ix)  # the cell the most edges act over, at start
        nodes = nodes_of(server)

        # the cells: one mesh per label in the label's colour, a tile (8 vertices) per cell centred on it
        for name, level, rgb in (("unreachable", 0, style.UNREACHABLE), ("npm", 1, style.NPM), ("pm", 2, style.PM)):
            node = nodes[f"/map/cells/{name}"]
            cy, cx = np.nonzero(labels == level)
            if not len(cy):
                assert not node.fields["visible"]
                continue
            assert node.type == "MeshMessage" and tuple(node.fields["props"]["color"]) == rgb
            got = node.array("props", "vertices").reshape(-1, 8, 3).mean(axis=1)
            want = np.stack([xs[cx], ys[cy], np.full(len(cx), style.CELL_HEIGHT / 2)], axis=1)
            np.testing.assert_allclose(got, want, atol=1e-6)
        assert (labels == 1).sum() > 0 and (labels == 0).sum() > 0

        # the arm: each capsule where C MuJoCo puts it in the failure's park pose
        m = robot.mj
        d = mujoco.MjData(m)
        d.qpos[:] = park_pose(robot, data.failure)
        for j, a in data.failure.locked:
            assert d.qpos[j - 1] == pytest.approx(a)  # locked joints at their angles
        mujoco.mj_forward(m, d)
        arm = {k: v for k, v in nodes.items() if k.startswith("/map/arm/")}
        capsules = [g for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE]
        assert len(arm) == len(capsules)
        for g in capsules:
            node = arm[f"/map/arm/{m.geom(g).name}"]
            np.testing.assert_allclose(node.fields["position"], d.geom_xpos[g], atol=1e-6)

        # the edges: 40 of the cell's, evenly spaced by id, each its interaction point's path
        ids, paths = plain_cell_edges(small_map, iy, ix)
        assert len(ids) > 40
        pick = np.unique(np.linspace(0, len(ids) - 1, 40).round().astype(int))
        np.testing.assert_array_equal(view.selected.ids, ids)
        np.testing.assert_array_equal(view.selected.drawn, ids[pick])
        segs = nodes["/map/edges/paths"].array("props", "points").reshape(-1, 2, 3)
        want = np.concatenate([np.stack([paths[k][:-1], paths[k][1:]], axis=1) for k in pick])
        np.testing.assert_allclose(segs, want, atol=1e-6)
        colours = nodes["/map/edges/paths"].array("props", "colors").reshape(-1, 2, 3)
        with h5py.File(small_map, "r") as f:
            duration = f["edges/duration"][...][ids[pick]]
        first = np.cumsum([0] + [len(paths[k]) - 1 for k in pick[:-1]])
        order = np.argsort(duration)  # cyan (short) to magenta (long): red grows with the duration
        assert np.all(np.diff(colours[first, 0, 0][order].astype(int)) >= 0)
        assert colours[first[order[0]], 0].tolist() == [0, 255, 255]
        assert colours[first[order[-1]], 0].tolist() == [255, 0, 255]

        # the selected cell's outline encloses its square
        outline = nodes["/map/selected/outline"].array("props", "points").reshape(-1, 3)
        assert outline[:, 0].min() == pytest.approx(xs[ix] - data.cell / 2, abs=1e-6)
        assert outline[:, 1].max() == pytest.approx(ys[iy] + data.cell / 2, abs=1e-6)

        # the swept arm: a mesh per edge, each the arm's capsules at SWEPT_POSES states
        view.drawing = "arm swept along"
        view.cap = 3
        view.select(iy, ix)
        nodes = nodes_of(server)
        assert "/map/edges/paths" not in nodes
        swept = [k for k in nodes if k.startswith("/map/edges/swept/")]
        assert len(swept) == 3


def test_a_click_selects_the_cell_under_it(small_map, server):
    from lmjx.view.map import MapView, MapViewSettings
    from lmjx.view.mapdata import MapData

    with MapData(small_map) as data:
        view = MapView(server, data, MapViewSettings(cap=5))
        iy, ix = np.argwhere(data.labels_smooth >= 1)[3]
        target = np.array([data.xs[ix] + 0.3 * data.cell, data.ys[iy] - 0.3 * data.cell, style.CELL_HEIGHT])
        origin = np.array([1.2, -0.8, 1.0])
        ray = (target - origin) / np.linalg.norm(target - origin)
        view._clicked(SimpleNamespace(ray_origin=tuple(origin), ray_direction=tuple(ray)))
        assert (view.selected.iy, view.selected.ix) == (iy, ix)
        assert (view.pick_iy.value, view.pick_ix.value) == (iy, ix)  # the picker follows


def test_opening_reads_the_reach_map_and_offsets_only(small_map, monkeypatch):
    from lmjx.view.mapdata import MapData

    reads: list[str] = []
    read = h5py.Dataset.__getitem__

    def spy(self, key):
        reads.append(self.name)
        return read(self, key)

    monkeypatch.setattr(h5py.Dataset, "__getitem__", spy)
    with MapData(small_map) as data:
        assert set(reads) == {"/reach/x", "/reach/y", "/reach/labels", "/reach/labels_smooth", "/edges/index/offset"}
        assert not data._columns and not data._states
        reads.clear()
        iy, ix = data.busiest_cell()
        sel = data.cell_edges(iy, ix, 7, "peak torque ratio")
        assert len(sel.drawn) == 7
        # the cell's slice of the index, the per-edge arrays its drawing needs, the states of the drawn edges
        assert set(reads) == {f"/edges/{k}" for k in ("index/edges", "offset", "length", "peak_torque_ratio", "site")}
        assert set(data._states) == {"p"}
        with h5py.File(small_map, "r") as f:
            np.testing.assert_array_equal(sel.p[3], f["edges/p"][f["edges/offset"][sel.drawn[3]] :][: len(sel.p[3])])


def test_a_map_that_is_not_a_map_is_refused_in_one_line(tmp_path, small_map):
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    fake = tmp_path / "fake.h5"
    fake.write_text("not hdf5")
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.arange(3)
    cli("view", tmp_path / "missing.h5").one_line_error("does not exist")
    cli("view", text).one_line_error(
        "is not an lmjx map (.h5), a scene file (.toml), a trial record (.json) or an evaluation folder"
    )
    cli("view", fake).one_line_error("is not an HDF5 file")
    cli("view", other).one_line_error("not an lmjx map")
    cli("view", tmp_path).one_line_error("not an evaluation")
    cli("view", small_map, "--cell", "999,0").one_line_error("is off the map")
    cli("view", small_map, "--port", "70000").one_line_error("out of range")
    cli("view", small_map, "--html", tmp_path / "x.png").one_line_error("give a name ending in .html")


def test_a_busy_port_is_refused_in_one_line(small_map):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        cli("view", small_map, "--port", port).one_line_error(f"port {port} on 127.0.0.1 is in use")


def test_without_viser_it_says_how_to_install_it(small_map, monkeypatch):
    monkeypatch.setitem(sys.modules, "viser", None)  # import viser raises ImportError
    cli("view", small_map).one_line_error("lmjx view needs viser: pip install -e '.[view]'")


def test_html_export_holds_the_scene_and_is_written_whole(small_map, tmp_path):
    out = tmp_path / "map.html"
    r = cli("view", small_map, "--html", out, "--edges", "10", "--json").ok()
    summary = json.loads(r.stdout)
    assert summary["html"] == str(out) and summary["bytes"] == out.stat().st_size
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.html"]  # no temporary file left
    html = out.read_text()
    data = re.search(r'window.__VISER_EMBED_DATA__="([A-Za-z0-9+/=]+)"', html)
    assert data is not None and "<script" in html and "http://" not in html.split("__VISER_EMBED_DATA__")[0][-200:]
    nodes = latest_nodes(decode_recording(base64.b64decode(data.group(1)))[1])
    assert {"/map/table", "/map/cells/npm", "/map/edges/paths", "/map/selected/tile"} <= set(nodes)
    assert len(nodes["/map/edges/paths"].array("props", "points")) > 0
    # readable alone: a title, and a legend that names every colour the page shows, in those colours
    assert "<title>Reach-Ability map case2.h5 - lmjx view</title>" in html
    legend = html[html.index('id="lmjx-legend"') :]
    for key in ("pm", "npm", "unreachable", "arm", "selected", "edges"):
        swatch = style.SWATCHES[key]
        assert f"<b>{swatch.name}</b>" in legend and (key == "edges" or swatch.css in legend)


def test_one_colour_scheme_for_the_labels(small_map):
    """reach --png, the views, README.md, docs/VIEW.md and view --help name the same colours."""
    from pathlib import Path

    from lmjx.reach.plots import COLORS
    from lmjx.reach.reachability import NPM, PM, UNREACHABLE

    assert COLORS == style.LABEL_HEX and {style.hex_rgb(COLORS[k]) for k in (UNREACHABLE, NPM, PM)} == {
        style.UNREACHABLE, style.NPM, style.PM}  # fmt: skip
    words = style.LABEL_WORDS
    root = Path(__file__).parent.parent
    readme = root.joinpath("README.md").read_text()
    assert f"Green: grasp (PM); {words[1]}: push or poke only (NPM); {words[0]}: unreachable" in readme
    view_md = root.joinpath("docs", "VIEW.md").read_text()
    help_text = cli("view", "--help").stdout.replace("\n", " ")
    for text in (view_md, " ".join(help_text.split())):
        assert f"PM {words[2]}, NPM {words[1]}, unreachable {words[0]}" in text
        assert not [line for line in text.splitlines() if "NPM" in line and ("orange" in line or "yellow" in line)]


def test_the_map_camera_frames_the_cells_and_the_arm(small_map, server):
    from lmjx.view.map import MapView, MapViewSettings, arm_extent, cells_extent
    from lmjx.view.mapdata import MapData

    with MapData(small_map) as data:
        view = MapView(server, data, MapViewSettings(cap=3))
        points = np.concatenate([cells_extent(data.xs, data.ys, data.cell), arm_extent(view.poser, view.park)])
        assert_framed(points, view.camera)


def project(points: np.ndarray, camera: tuple, aspect: float = style.ASPECT) -> np.ndarray:
    """(n, 2) points in the picture's normalised coordinates (-1..1 across its width and height)
    of world points seen by `camera`, as three.js's perspective camera projects them."""
    pos, look, fov = (np.asarray(camera[0], float), np.asarray(camera[1], float), camera[2])
    f = (look - pos) / np.linalg.norm(look - pos)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    d = np.asarray(points, float) - pos
    x, y, z = d @ r, d @ u, d @ f
    assert (z > 0).all()
    t = np.tan(fov / 2)
    return np.stack([x / (z * t * aspect), y / (z * t)], axis=1)


def assert_framed(points: np.ndarray, camera: tuple) -> None:
    """Every point inside the picture, within its margin, and the picture no larger than needed."""
    xy = np.abs(project(points, camera))
    assert xy.max() <= 1 - style.MARGIN + 1e-6
    assert xy.max() >= 1 - style.MARGIN - 1e-3  # as close as it can be: a point on the margin


# ------------------------------------------------------------------------------ scenes

BENCH = Path(__file__).parent.parent / "examples" / "my_bench.toml"  # a scene file with a fixed obstacle


def test_a_scene_file_is_drawn_before_planning(plan_map, tmp_path):
    """lmjx view SCENE.toml --map M --html: the table, the boxes at their nominal poses, the
    fixed obstacle, the goal region over the map's reach cells, the arm in the map's park
    pose; a title and a legend; without a map, the scene alone."""
    import lmjx
    from lmjx.model.robot import load_robot
    from lmjx.planner.clearance import park_pose

    out = tmp_path / "scene.html"
    cli("view", BENCH, "--map", plan_map, "--html", out).ok()
    nodes = embedded_nodes(out)
    task = lmjx.load_scene(BENCH)
    sc = task.scenario
    for b in sc.movable:
        body = nodes[f"/scene/bodies/{b.name}"]
        np.testing.assert_allclose(body.fields["position"][:2], (b.x, b.y), atol=1e-9)
    for b in sc.fixed:
        np.testing.assert_allclose(nodes[f"/scene/static/{b.name}"].fields["position"][:2], (b.x, b.y), atol=1e-9)
    goal = nodes["/scene/static/goal"]
    np.testing.assert_allclose(goal.fields["position"][:2], sc.goal_center, atol=1e-9)
    assert goal.fields["position"][2] > style.CELL_HEIGHT  # over the cells
    assert {"/scene/cells/npm", "/scene/cells/unreachable", "/scene/labels/goal"} <= set(nodes)
    with h5py.File(plan_map, "r") as f:
        npm = int((f["reach/labels_smooth"][...] == 1).sum())
    assert len(nodes["/scene/cells/npm"].array("props", "vertices")) // 24 == npm  # 8 vertices of 3 per tile
    robot = load_robot("panda")
    m = robot.mj
    d = mujoco.MjData(m)
    from lmjx.view.mapdata import MapData

    with MapData(plan_map) as data:
        d.qpos[:] = park_pose(robot, data.failure)
    mujoco.mj_kinematics(m, d)
    for b in range(1, m.nbody):
        if m.body_jntnum[b]:
            np.testing.assert_allclose(nodes[f"/scene/bodies/{m.body(b).name}"].fields["position"], d.xpos[b],
                                       atol=1e-6)  # fmt: skip
    html = out.read_text()
    assert "<title>Scene my bench - lmjx view</title>" in html
    for key in ("pm", "npm", "unreachable", "arm", "target", "obstacles", "fixed", "goal"):
        assert f"<b>{style.SWATCHES[key].name}</b>" in html[html.index('id="lmjx-legend"') :]
    alone = tmp_path / "alone.html"
    cli("view", BENCH, "--html", alone).ok()
    assert not any(k.startswith("/scene/cells") for k in embedded_nodes(alone))
    assert "<b>NPM</b>" not in alone.read_text()[alone.read_text().index('id="lmjx-legend"') :]


def test_a_bad_scene_file_is_one_line(plan_map, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("format = [")
    cli("view", bad).one_line_error("not TOML")
    bad.write_text(BENCH.read_text().replace("budget = 12", "budget = 0"))
    cli("view", bad, "--map", plan_map).one_line_error("budget: give a whole number 1 to 10000, got 0")
    far = tmp_path / "far.toml"
    text = BENCH.read_text().replace("distance = 0.15 ", "center = [-0.35, -0.9]\n#")
    far.write_text(text.replace("angle = 80.0", ""))
    cli("view", far, "--map", plan_map).one_line_error("no reachable cell of the map (NPM or PM) lies under the goal")
    cli("view", BENCH, "--trial", "case2/1/random/1").one_line_error("not of a scene file")
    cli("view", BENCH, "--map", plan_map, "--map", plan_map).one_line_error("give --map once")
    cli("view", tmp_path / "none.toml").one_line_error("does not exist")


# ------------------------------------------------------------------------------ trials, by today's commands


def embedded_nodes(html_path) -> dict:
    data = re.search(r'window.__VISER_EMBED_DATA__="([A-Za-z0-9+/=]+)"', html_path.read_text())
    assert data is not None
    return latest_nodes(decode_recording(base64.b64decode(data.group(1)))[1])


def _plan(plan_map, folder, *which: object) -> Path:
    """lmjx plan --json of one action (Random: no simulation of candidates), written to a file."""
    r = cli("plan", "--map", plan_map, *which, "--asm", "random", "--seed", "0", "--max-actions", "1", "--set",
            "turn_edges=false", "--json").ok()  # fmt: skip
    path = folder / "plan.json"
    path.write_text(r.stdout)
    record = json.loads(r.stdout)
    assert record["actions"] == 1 and "scene" in record
    return path


@pytest.fixture(scope="module")
def trial_json(plan_map, tmp_path_factory):
    """A trial of shipped scenario 1 (its record's scene: the scenario's number and task set)."""
    return _plan(plan_map, tmp_path_factory.mktemp("trial"), "--scenario", "1")


@pytest.fixture(scope="module")
def scene_trial_json(plan_map, tmp_path_factory):
    """A trial of a scene file (its record's scene: the file's text)."""
    return _plan(plan_map, tmp_path_factory.mktemp("scene_trial"), "--scene", BENCH)


@pytest.fixture(scope="module")
def evaluation(plan_map, tmp_path_factory):
    """lmjx evaluate's folder: one trial of one action of a scene file (numbered 1 there)."""
    out = tmp_path_factory.mktemp("evaluation") / "eval"
    cli("evaluate", "--failures", "case2", "--scenes", BENCH, "--asms", "random", "--trials", "1", "--max-actions",
        "1", "--maps", plan_map.parent, "--out", out).ok()  # fmt: skip
    results = json.loads((out / "results.json").read_text())
    assert results["format_version"] == 2 and len(results["trials"]) == 1
    return out


def test_a_trial_replays_as_recorded_and_is_drawn(trial_json, plan_map, robot, server):
    from lmjx.mapfile.read import load_map
    from lmjx.sim.scenarios import resolve_task
    from lmjx.view.replay import replay
    from lmjx.view.trial import TrialView, extent_points
    from lmjx.view.trialrecord import read_trial

    record = read_trial(trial_json, None)
    plan = json.loads(trial_json.read_text())
    assert record.scene is not None and record.scene["kind"] == "shipped"
    with load_map(plan_map, lazy=True) as m:
        rep = replay(robot, m, record)
    assert rep.complete and rep.first_disagreement() is None and rep.scene_matches
    assert rep.task == resolve_task(1, robot, plan["tasks"])
    for a, s in zip(rep.actions, [s for s in plan["steps"] if s["edge"] >= 0], strict=True):
        assert a.edge == s["edge"] and a.route == s["transit_route"]
        assert a.moved_m == pytest.approx(s["target_moved_m"], abs=1.5e-4)
        assert a.start <= a.edge_start <= a.end
    sc = rep.task.scenario
    end = rep.actions[-1].target_after
    assert np.hypot(*(end[:2] - np.array(sc.goal_center))) == pytest.approx(plan["final_distance_m"], abs=1.5e-3)

    view = TrialView(server, rep, at=len(rep.frames) - 1)
    nodes = nodes_of(server)
    target = nodes["/trial/bodies/target"]
    # (MuJoCo's body positions lag a step behind its joint positions: micrometres)
    np.testing.assert_allclose(target.fields["position"], end, atol=1e-4)  # at the last frame
    assert "/trial/static/goal" in nodes and "/trial/static/table" in nodes and "/trial/labels/goal" in nodes
    for a in rep.actions:
        assert f"/trial/actions/{a.index + 1}/edge" in nodes
    view.show(0)
    nodes = nodes_of(server)
    np.testing.assert_allclose(nodes["/trial/bodies/target"].fields["position"], rep.actions[0].target_before,
                               atol=1e-6)  # fmt: skip
    # the camera frames the arm and the objects over the whole trial (every frame), the goal and the fixed ones
    every = extent_points(rep.model, rep.frames, sc, picks=len(rep.frames))
    xy = np.abs(project(every, view.camera))
    assert xy.max() <= 1 - style.MARGIN + 0.02  # (the camera samples CAMERA_FRAMES frames)


def test_a_scene_files_trial_replays_in_its_scene(scene_trial_json, plan_map, tmp_path):
    """plan --scene's record rebuilds its task from the record alone (the map holds no such
    scenario number); a record whose scene's digest differs says so in one line; a record
    that keeps no scene falls back to its scenario's number, which a scene file's has not."""
    import lmjx
    from lmjx.model.robot import load_robot
    from lmjx.view.trialrecord import read_trial, trial_task

    record = read_trial(scene_trial_json, None)
    plan = json.loads(scene_trial_json.read_text())
    assert plan["scenario"] == 0 and record.scene["kind"] == "scene"
    task, matches = trial_task(record, load_robot("panda"))
    assert matches and task.scenario == lmjx.load_scene(BENCH).scenario
    out = tmp_path / "trial.html"
    r = cli("view", scene_trial_json, "--map", plan_map, "--html", out).ok()
    assert "differs" not in r.stderr and "/trial/static/shelf_post" in embedded_nodes(out)
    html = out.read_text()
    assert "<title>Trial case2/0/random/0 - lmjx view</title>" in html and "scene my bench" in html
    assert "The replay agrees with the record" in html

    edited = dict(plan, scene=dict(plan["scene"], digest="0" * 16))
    path = tmp_path / "edited.json"
    path.write_text(json.dumps(edited))
    r = cli("view", path, "--map", plan_map, "--html", tmp_path / "edited.html").ok()
    said = [line for line in r.stderr.splitlines() if "differs" in line]
    assert len(said) == 1 and "the scene of trial case2/0/random/0 differs from the one its record describes" in said[0]

    without = {k: v for k, v in plan.items() if k != "scene"}
    path.write_text(json.dumps(without))
    cli("view", path, "--map", plan_map).one_line_error("keeps no scene and names scenario 0 of the task set 'custom'")


def test_an_evaluations_trials_by_folder_and_by_file(evaluation, plan_map, tmp_path, server):
    from lmjx.view.evaluation import EvaluationView, report_table
    from lmjx.view.trialrecord import from_dict

    results = json.loads((evaluation / "results.json").read_text())
    record = results["trials"][0]
    key = f"case2/{record['scenario']}/random/{record['seed']}"
    view = EvaluationView(server, evaluation, [str(plan_map)])
    assert len(view.records) == 1 and "my bench" in report_table(evaluation, view.records)
    shown = view.open(from_dict(record, str(evaluation / "results.json")))
    assert len(shown.rep.actions) == record["actions"] and shown.rep.first_disagreement() is None
    assert shown.rep.task.name == "my bench"

    for where in (evaluation, evaluation / "results.json"):
        out = tmp_path / "t.html"
        r = cli("view", where, "--trial", key, "--map", plan_map, "--html", out, "--json").ok()
        assert json.loads(r.stdout)["kind"] in ("evaluation", "trial") and f"Trial {key}" in out.read_text()
    cli("view", evaluation, "--trial", "case2/1/greedy/12345").one_line_error("no trial case2/1/greedy/12345 in")
    cli("view", evaluation / "results.json").one_line_error("holds an evaluation's 1 trials; choose one with --trial")
    cli("view", evaluation, "--trial", "case2-1").one_line_error("give failure/scenario/asm/seed")

    # the same records as a bare list (results written without provenance) read alike
    folder = tmp_path / "bare"
    folder.mkdir()
    (folder / "results.json").write_text(json.dumps(results["trials"]))
    cli("view", folder, "--trial", key, "--map", plan_map, "--html", tmp_path / "bare.html").ok()
    # another format version, and records without their actions: one line each
    (folder / "results.json").write_text(json.dumps(dict(results, format_version=99)))
    cli("view", folder, "--trial", key).one_line_error("is a results file of format 99; this lmjx reads format 2")
    (folder / "results.json").write_text(json.dumps(dict(results, trials=[{k: v for k, v in record.items()
                                                                            if k != "steps"}])))  # fmt: skip
    cli("view", folder, "--trial", key, "--map", plan_map).one_line_error("does not list the trial's actions")
    text = cli("view", folder, "--trial", key, "--map", plan_map).stderr
    assert "older" not in text


def test_trial_record_mistakes_are_one_line(trial_json, plan_map, tmp_path):
    plan = json.loads(trial_json.read_text())
    key = f"case2/1/random/{plan['seed']}"
    cli("view", trial_json, "--trial", key).one_line_error("holds one trial")
    cli("view", trial_json, "--map", tmp_path / "none.h5").one_line_error("does not exist")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(dict(plan, scene={"kind": "drawn by hand"})))
    cli("view", bad, "--map", plan_map).one_line_error("its record of the scene is not one lmjx writes")


# ------------------------------------------------------------------------------ an MJCF's meshes

MESH_ARM = """
<mujoco>
  <asset><mesh name="shell" vertex="0 0 0  0.1 0 0  0 0.1 0  0 0 0.3  0.1 0.1 0.3"/></asset>
  <worldbody>
    <body name="link1">
      <joint name="j1" axis="0 0 1"/>
      <geom name="link1_c0" type="capsule" fromto="0 0 0 0 0 0.3" size="0.04"/>
      <geom name="link1_visual" type="mesh" mesh="shell" contype="0" conaffinity="0"/>
      <body name="link2" pos="0 0 0.3">
        <joint name="j2" axis="0 1 0"/>
        <geom name="link2_c0" type="capsule" fromto="0 0 0 0.2 0 0" size="0.03"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_an_mjcfs_meshes_are_drawn_where_it_has_them(server):
    """A body with a mesh geom is drawn with the mesh's own triangles (MuJoCo's mesh_vert,
    mesh_face) in the geom's pose; a body without one with its capsules."""
    from lmjx.view.map import draw_arm
    from lmjx.view.shapes import ArmPoser, arm_geoms

    m = mujoco.MjModel.from_xml_string(MESH_ARM)
    geoms = arm_geoms(m, {"link1", "link2"})
    assert [m.geom(int(g)).name for g in geoms] == ["link1_visual", "link2_c0"]
    q = np.array([0.4, -0.3])
    draw_arm(server, "/arm", ArmPoser(m, np.array([0, 1]), geoms), q)
    nodes = nodes_of(server)
    assert set(k for k in nodes if k.startswith("/arm/")) == {"/arm/link1_visual", "/arm/link2_c0"}
    mesh = nodes["/arm/link1_visual"]
    g = m.geom("link1_visual").id
    np.testing.assert_array_equal(mesh.array("props", "vertices").reshape(-1, 3), m.mesh_vert)
    np.testing.assert_array_equal(mesh.array("props", "faces").reshape(-1, 3), m.mesh_face)
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    np.testing.assert_allclose(mesh.fields["position"], d.geom_xpos[g], atol=1e-6)
    # the mesh's vertices placed by the node's pose are where MuJoCo puts them
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, np.asarray(mesh.fields["wxyz"], float))
    placed = m.mesh_vert @ R.reshape(3, 3).T + mesh.fields["position"]
    np.testing.assert_allclose(placed, m.mesh_vert @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g], atol=1e-6)
