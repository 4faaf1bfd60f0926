"""`lmjx view`: the scene the viewer's server sends (decoded from viser's scene recording, as a
browser receives it) checked against the map file read with plain h5py and against C MuJoCo;
lazy reading; a trial replayed from its record; the HTML export; one-line errors.  What a
browser draws of it is tested in test_view_browser.py (where Chromium is installed)."""

from __future__ import annotations

import base64
import json
import re
import socket
import sys
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

        # the cells: one instanced mesh per label, one instance per cell at its centre
        for name, level in (("npm", 1), ("pm", 2)):
            node = nodes[f"/map/cells/{name}"]
            assert node.type == "BatchedMeshesMessage"
            got = node.array("props", "batched_positions").reshape(-1, 3)
            cy, cx = np.nonzero(labels == level)
            want = np.stack([xs[cx], ys[cy], np.full(len(cx), style.CELL_HEIGHT / 2)], axis=1)
            np.testing.assert_allclose(got, want, atol=1e-6)
        assert len(nodes["/map/cells/npm"].array("props", "batched_positions")) // 3 == int((labels == 1).sum()) > 0

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
    cli("view", text).one_line_error("is not an lmjx map (.h5), a trial record (.json) or an evaluation folder")
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


# ------------------------------------------------------------------------------ trials


@pytest.fixture(scope="module")
def trial_json(plan_map, tmp_path_factory):
    """A Random trial of three actions on the planner tests' map, the map's own edges (seed 7: it
    reaches the goal, where the target ends at rest)."""
    r = cli("plan", "--map", plan_map, "--scenario", "1", "--asm", "random", "--seed", "7", "--max-actions", "3",
            "--set", "turn_edges=false", "--json").ok()  # fmt: skip
    path = tmp_path_factory.mktemp("trial") / "plan.json"
    path.write_text(r.stdout)
    record = json.loads(r.stdout)
    assert record["actions"] >= 2
    return path


def test_a_trial_replays_as_recorded_and_is_drawn(trial_json, plan_map, robot, server):
    from lmjx.mapfile.read import load_map
    from lmjx.sim.scenarios import scenario
    from lmjx.view.replay import replay
    from lmjx.view.trial import TrialView
    from lmjx.view.trialrecord import read_trial

    record = read_trial(trial_json, None)
    plan = json.loads(trial_json.read_text())
    with load_map(plan_map, lazy=True) as m:
        rep = replay(robot, m, record)
    assert rep.complete and rep.first_disagreement() is None
    for a, s in zip(rep.actions, [s for s in plan["steps"] if s["edge"] >= 0], strict=True):
        assert a.edge == s["edge"] and a.route == s["transit_route"]
        assert a.moved_m == pytest.approx(s["target_moved_m"], abs=1.5e-4)
        assert a.start <= a.edge_start <= a.end
    sc = scenario(record.scenario, robot.profile.task_scale, record.tasks)
    end = rep.actions[-1].target_after
    assert np.hypot(*(end[:2] - np.array(sc.goal_center))) == pytest.approx(plan["final_distance_m"], abs=1.5e-4)

    view = TrialView(server, rep, at=len(rep.frames) - 1)
    nodes = nodes_of(server)
    target = nodes["/trial/bodies/target"]
    # (MuJoCo's body positions lag a step behind its joint positions: micrometres, at rest none)
    np.testing.assert_allclose(target.fields["position"], end, atol=1e-6)  # at the last frame
    assert "/trial/static/goal" in nodes and "/trial/static/table" in nodes
    for a in rep.actions:
        assert f"/trial/actions/{a.index + 1}/edge" in nodes
    view.show(0)
    nodes = nodes_of(server)
    np.testing.assert_allclose(nodes["/trial/bodies/target"].fields["position"], rep.actions[0].target_before,
                               atol=1e-6)  # fmt: skip


def test_a_trial_of_an_evaluation_and_its_mistakes(trial_json, plan_map, tmp_path, server):
    from lmjx.view.evaluation import EvaluationView, report_table
    from lmjx.view.trialrecord import from_dict

    plan = json.loads(trial_json.read_text())
    folder = tmp_path / "eval"
    folder.mkdir()
    keys = ("robot", "tasks", "failure", "scenario", "asm", "seed", "success", "actions", "planning_s", "execution_s",
            "final_distance_m", "end", "asm_settings")  # fmt: skip
    record = {k: plan[k] for k in keys}
    record["steps"] = [s for s in plan["steps"] if s["edge"] >= 0]
    (folder / "results.json").write_text(json.dumps([record]))
    view = EvaluationView(server, folder, [str(plan_map)])
    assert "| case2 | 1 | random | 1 |" in report_table(folder, view.records)
    shown = view.open(from_dict(record, str(folder / "results.json")))
    assert len(shown.rep.actions) == plan["actions"]

    key = f"case2/1/random/{plan['seed']}"
    cli("view", folder, "--trial", "case2/1/greedy/12345").one_line_error("no trial case2/1/greedy/12345 in")
    cli("view", folder / "results.json").one_line_error("choose one with --trial")
    cli("view", folder, "--trial", "case2-1").one_line_error("give failure/scenario/asm/seed")
    cli("view", trial_json, "--trial", key).one_line_error("holds one trial")
    cli("view", trial_json, "--map", tmp_path / "none.h5").one_line_error("does not exist")
    old = dict(record)
    del old["steps"]
    (folder / "results.json").write_text(json.dumps([old]))
    cli("view", folder, "--trial", key, "--map", plan_map).one_line_error("does not list the trial's actions")
