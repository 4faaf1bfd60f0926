"""docs/API.md, the reference for other planners: every ```python block runs as written (in
order, in one namespace, where `make run`'s map is the planner tests' `plan_map`); every
function of its table has an example; an exported trajectory, read back without lmjx, replays
in C MuJoCo to the map's stored states; examples/push_with_my_rule.py runs on the public API
alone and imports nothing private."""

from __future__ import annotations

import ast
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import lmjx

ROOT = Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "API.md"
EXAMPLE = ROOT / "examples" / "push_with_my_rule.py"
PYTHON_BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)
REPLAY_TOLERANCE = 1e-6  # [rad]


@pytest.fixture
def api_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, plan_map: Path) -> Path:
    (tmp_path / "maps").mkdir()
    shutil.copy(plan_map, tmp_path / "maps" / "case2.h5")
    shutil.copytree(ROOT / "examples", tmp_path / "examples")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_the_api_page_runs_as_written(api_dir: Path) -> None:
    blocks = PYTHON_BLOCK.findall(PAGE.read_text())
    namespace: dict = {"__name__": "__main__"}
    for i, block in enumerate(blocks, 1):
        exec(compile(block, f"docs/API.md, python block {i}", "exec"), namespace)
    assert namespace["ok"], "no edge over the target has a transit: the page shows nothing"
    assert len(namespace["robot_side"].sent) == 1 and (api_dir / "edge.csv").exists()


def test_every_function_on_the_page_has_an_example() -> None:
    text = PAGE.read_text()
    code = "\n".join(PYTHON_BLOCK.findall(text))
    table = re.findall(r"^\| \[`([^`]+)`", text, re.M)
    assert len(table) == 8, table
    for entry in table:
        for name in re.findall(r"(?:^|, )`?([A-Za-z_.]+)(?:\(|`|$)", entry) or [entry]:
            short = name.split(".")[-1]
            assert short in dir(lmjx) or short in dir(lmjx.MapFile), name
            assert re.search(rf"\b{re.escape(short)}\b", code), f"{name}: no example on the page"


REPLAY = r"""
import csv, json, sys
import h5py, mujoco, numpy as np

mjcf, map_path, csv_path, json_path, edge, point = sys.argv[1:7]
edge = int(edge)
with open(csv_path) as f:
    rows = list(csv.reader(f))
names = rows[0][1:]
nj = len(names) // 3
table = np.array(rows[1:], dtype=float)
t, q, qd = table[:, 0], table[:, 1 : 1 + nj], table[:, 1 + nj : 1 + 2 * nj]
msg = json.load(open(json_path))
assert msg["joint_names"] == names[:nj] and [n + "_velocity" for n in names[:nj]] == names[nj : 2 * nj]
stamps = [p["time_from_start"]["sec"] + p["time_from_start"]["nanosec"] * 1e-9 for p in msg["points"]]
assert np.abs(np.array(stamps) - t).max() <= 1e-9
assert np.array_equal([p["positions"] for p in msg["points"]], q)
assert np.array_equal([p["velocities"] for p in msg["points"]], qd)
m = mujoco.MjModel.from_xml_path(mjcf)
adr = [m.joint(n).qposadr[0] for n in names[:nj]]
with h5py.File(map_path, "r") as f:  # the map's stored states, as maps/README.md reads them
    g = f["edges"]
    o, n = int(g["offset"][edge]), int(g["length"][edge])
    stored_q, stored_p, dt = g["q"][o : o + n], g["p"][o : o + n], float(g.attrs["dt"])
site = m.site("ip_" + point).id
# replay: integrate each point's velocities over its interval with MuJoCo, from the first point
qpos = np.zeros(m.nq)
qpos[adr] = q[0]
d = mujoco.MjData(m)
replayed = [qpos[adr].copy()]
for i in range(len(t) - 1):
    vel = np.zeros(m.nv)
    vel[[m.joint(x).dofadr[0] for x in names[:nj]]] = qd[i]
    mujoco.mj_integratePos(m, qpos, vel, t[i + 1] - t[i])
    replayed.append(qpos[adr].copy())
replayed = np.array(replayed)
k = np.round(t / dt).astype(int)
at = np.abs(t - k * dt) < 1e-9
err_q = float(np.abs(replayed[at] - stored_q[k[at]]).max())
points = []
for row in replayed[at]:
    d.qpos[adr] = row
    mujoco.mj_kinematics(m, d)
    points.append(d.site_xpos[site].copy())
err_p = float(np.abs(np.array(points) - stored_p[k[at]]).max())
print(json.dumps({"err_q": err_q, "err_p": err_p, "states": int(at.sum()), "stored": n,
                  "lmjx": any(x == "lmjx" or x.startswith("lmjx.") for x in sys.modules)}))
"""


def test_an_exported_trajectory_replays_in_c_mujoco_to_the_stored_states(plan_map: Path, tmp_path: Path) -> None:
    """Edges over the target of scenario 1, exported at 5 ms as CSV and JSON, read back in a
    process that imports csv, json, h5py, numpy and mujoco only: integrating each point's
    velocities with MuJoCo from the first point passes through every state the map stores
    within REPLAY_TOLERANCE, and MuJoCo's forward kinematics of them puts the interaction point
    on its stored path (float32 values: within 1e-5 m)."""
    with lmjx.load_map(plan_map) as m:
        ids = m.edges_over((0.36, 0.38, 0.44, 0.46))
        picked = [int(ids[0]), int(ids[len(ids) // 2]), int(ids[-1])]
        m_points = {i: m.edge(i).point for i in picked}
        for i in picked:
            e = m.edge(i)
            traj = lmjx.trajectory(e, 0.005)
            traj.write(tmp_path / f"{i}.csv")
            traj.write(tmp_path / f"{i}.json")
            assert len(traj.t) == 4 * (len(e.t) - 1) + 1 and traj.t[-1] == pytest.approx(e.t[-1], abs=1e-12)
            assert np.array_equal(traj.q[::4], e.q)  # every stored state, to the bit
        mjcf = str(m.robot.path)
    for i in picked:
        run = subprocess.run([sys.executable, "-c", REPLAY, mjcf, str(plan_map), str(tmp_path / f"{i}.csv"),
                              str(tmp_path / f"{i}.json"), str(i), m_points[i]], capture_output=True, text=True,
                             timeout=120)  # fmt: skip
        assert run.returncode == 0, run.stderr[-2000:]
        out = json.loads(run.stdout)
        assert not out["lmjx"] and out["states"] == out["stored"], out
        assert out["err_q"] < REPLAY_TOLERANCE and out["err_p"] < 1e-5, out


def test_edges_and_regions_are_the_planners(plan_map: Path) -> None:
    """edges_over of a target's square is the planner's `edges_over_target`; an edge is its
    bundle's states; a region or an edge that does not exist is one line."""
    from lmjx.planner.edge_planner import edges_over_target

    with lmjx.load_map(plan_map) as m:
        for x, y in ((0.403, 0.419), (0.471, 0.183), (0.553, 0.297)):  # (off the cells' edges: no float tie)
            r = 0.035
            want = edges_over_target(m.edges, m.reach, np.array([x, y]), 0.025, 0.01)
            assert np.array_equal(m.edges_over((x - r, y - r, x + r, y + r)), want)
        assert len(m.edges_over((-0.5, -1.0, -0.45, -0.95))) == 0
        i = int(m.edges_over((0.38, 0.40, 0.42, 0.44))[0])
        e, s = m.edge(i), m.edges.edge(i)
        assert np.array_equal(e.q, s["q"]) and np.array_equal(e.qd, s["qd"]) and np.array_equal(e.p, s["p"])
        assert e.t[1] == m.edges.config.dt and len(e.t) == m.edges.length[i] and e.joints == m.robot.joint_names
        assert e.point in m.robot.interaction_points and "\n" not in repr(e)
        for bad, message in ((m.edges.n_edges, "does not exist; the map has"), (-1, "does not exist")):
            with pytest.raises(lmjx.LmjxError, match=message):
                m.edge(bad)
        with pytest.raises(lmjx.LmjxError, match="xmin <= xmax"):
            m.edges_over((0.5, 0.0, 0.4, 0.1))
        with pytest.raises(lmjx.LmjxError, match=r"written as \.csv or \.json"):
            lmjx.trajectory(e).write("edge.txt")


def _lmjx_names(tree: ast.AST) -> set[str]:
    """Every lmjx module the source imports, and every attribute it takes of `lmjx`."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.split(".")[0] == "lmjx"}
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "lmjx":
            out.add(f"from {node.module}")
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "lmjx":
            out.add(f"lmjx.{node.attr}")
    return out


def test_the_example_imports_only_the_public_api() -> None:
    names = _lmjx_names(ast.parse(EXAMPLE.read_text()))
    private = sorted(n for n in names if n != "lmjx" and n.removeprefix("lmjx.") not in lmjx.__all__)
    assert not private, f"examples/push_with_my_rule.py uses what lmjx does not export: {private}"
    assert {"lmjx.transit", "lmjx.simulate", "lmjx.trajectory", "lmjx.load_scene"} <= names
    # (the check catches what it is for)
    assert _lmjx_names(ast.parse("import lmjx.sim.scenes\nfrom lmjx.api import x\nlmjx.toolkit")) == {
        "lmjx.sim.scenes", "from lmjx.api", "lmjx.toolkit"}  # fmt: skip


def test_the_example_pushes_with_its_own_rule(api_dir: Path) -> None:
    sys.path.insert(0, str(api_dir / "examples"))
    try:
        import push_with_my_rule as example
    finally:
        sys.path.pop(0)
    r = example.run("maps/case2.h5", "examples/my_bench.toml", seed=0, simulate=2, actions=1, export="out")
    assert len(r["edges"]) == 1 and r["end"] in ("goal", "budget"), r
    exported = list((api_dir / "out").glob("*.json"))
    edge, turn = r["edges"][0]
    assert len(exported) == 1 and f"edge{edge}_turn{round(np.degrees(turn))}" in exported[0].name
    points = json.loads(exported[0].read_text())["points"]
    assert not any(points[0]["velocities"]) and not any(points[-1]["velocities"])  # from rest to rest
    assert example.main(["maps/case2.h5", "examples/nothing.toml", "--actions", "1"]) == 2


def test_the_example_reaches_the_goal_with_turned_edges(api_dir: Path) -> None:
    """On the paper's scenario 3 (seed 0), the example's rule pushes the target into the goal
    with a turned copy of an edge (on this map, in one action: about 10 s on 2 CPU cores)."""
    sys.path.insert(0, str(api_dir / "examples"))
    try:
        import push_with_my_rule as example
    finally:
        sys.path.pop(0)
    r = example.run("maps/case2.h5", "3", seed=0, simulate=4, actions=3)
    assert r["success"] and r["end"] == "goal", r
    assert any(turn != 0.0 for _, turn in r["edges"]), r
