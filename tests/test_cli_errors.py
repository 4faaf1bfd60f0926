"""A newcomer's mistakes and missing optional parts: each ends in one line and exit
2, or works where working is right; never a traceback.  Commands run in this process except
where the setting must be there before MuJoCo or JAX starts (a process of its own)."""

from __future__ import annotations

import ctypes.util
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import benchmark_module, cli

import lmjx
from lmjx.evaluation.results import trials_of


def lmjx_process(*args: object, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lmjx.cli", *(str(a) for a in args)], capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, timeout=300)  # fmt: skip


def one_line(code: int, stderr: str, message: str, want: int = 2) -> None:
    lines = stderr.strip().splitlines()
    assert code == want and len(lines) == 1 and message in lines[0], (code, stderr)
    assert "Traceback" not in stderr


def test_version():
    r = cli("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"lmjx {lmjx.__version__}"


def test_device_gpu_without_a_gpu(tmp_path):
    # in this process JAX already runs on the CPU: refused before any work, the platform left as it was
    import jax

    jax.devices()  # started on the CPU (were it started by the command, it would start on no platform)
    for args in (("build-map", "--failure", "case2", "--out", tmp_path / "m.h5"),
                 ("plan", "--map", tmp_path / "m.h5", "--scenario", "1", "--asm", "random")):  # fmt: skip
        cli(*args, "--device", "gpu").one_line_error("no GPU is available to JAX")
    assert os.environ.get("JAX_PLATFORMS") == "cpu" and not list(tmp_path.iterdir())
    # a fresh process where JAX has no GPU backend at all (its AssertionError)
    r = lmjx_process("reach", "--failure", "case2", "--cell", "0.1", "--device", "gpu", env={"JAX_PLATFORMS": ""})
    if r.returncode == 0:
        pytest.skip("this machine has a GPU")
    one_line(r.returncode, r.stderr, "no GPU is available to JAX")


@pytest.mark.skipif(bool(ctypes.util.find_library("OSMesa")), reason="OSMesa is installed here")
def test_mujoco_gl_osmesa_without_osmesa():
    """MUJOCO_GL=osmesa without OSMesa: `import mujoco` itself fails; commands that draw nothing
    work, one that must draw says how to fix it in one line."""
    env = {"MUJOCO_GL": "osmesa"}
    r = lmjx_process("robots", "--json", env=env)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert {x["name"] for x in json.loads(r.stdout)["robots"]} >= {"panda", "ur5e"}
    r = lmjx_process("plan", "--map", "maps/none.h5", "--scenario", "1", "--asm", "random", "--render", "t.gif",
                     env=env)  # fmt: skip
    one_line(r.returncode, r.stderr, "MUJOCO_GL=osmesa but libOSMesa is not installed")
    assert "libosmesa6" in r.stderr


def test_robot_check_gives_mujocos_whole_message(tmp_path):
    path = tmp_path / "bad.xml"
    path.write_text("<mujoco><worldbody><body><geom type='box' size='1'/></body><foo/></worldbody></mujoco>")
    r = cli("robot", "check", path)
    one_line(r.returncode, r.stderr, "unrecognized element; Element 'foo', line 1")


def test_cache_dir_after_the_command_and_unwritable(tmp_path):
    keep = {"LMJX_CACHE_DIR": os.environ["LMJX_CACHE_DIR"]}  # restored after each command
    r = cli("robots", "--json", "--cache-dir", tmp_path / "cache", env=keep).ok()
    assert (tmp_path / "cache" / "jax").is_dir() and json.loads(r.stdout)["robots"]
    (tmp_path / "file").write_text("")
    r = cli("--cache-dir", tmp_path / "file" / "sub", "robots", env=keep)
    one_line(r.returncode, r.stderr, "warning: cannot write the compile cache", want=0)
    assert "panda" in r.stdout


def test_output_formats_from_the_extension(tmp_path):
    cli("reach", "--failure", "case2", "--png", tmp_path / "r.bmp").one_line_error("cannot write a figure with '.bmp'")
    cli("reach", "--failure", "case2", "--png", tmp_path / "r").one_line_error("no extension")
    cli("reach", "--failure", "case2", "--out", tmp_path / "r.json").one_line_error("written as HDF5")
    cli("lock-search", "--joints", "J6,J7", "--out", tmp_path / "r.h5").one_line_error("written as JSON")
    cli("bench", "--out", tmp_path / "b.txt").one_line_error("written as JSON")
    assert not list(tmp_path.iterdir())
    # the same small map as tests/test_cli.py's (its program compiled once), drawn as a JPEG
    jpg = tmp_path / "r.jpg"
    cli("reach", "--failure", "case1", "--cell", "0.1", "--png", jpg).ok()
    assert jpg.read_bytes()[:3] == b"\xff\xd8\xff"


def test_lock_search_warns_when_its_best_lock_reaches_nothing(monkeypatch, tmp_path):
    import lmjx.reach.locksearch as ls

    def nothing(joints, grids, config, robot=None, base=None, progress=False):
        shape = tuple(len(g) for g in grids)
        pm = np.zeros(shape)
        npm = np.zeros(shape)
        npm[0, 0] = pm[0, 0] = 0.1  # the one lock that reaches something has PM: not 'best'
        return ls.LockSearchResult(tuple(joints), tuple(grids), pm, npm, 0.0)

    monkeypatch.setattr(ls, "lock_search", nothing)
    r = cli("lock-search", "--joints", "J6,J7", "--grid", "2", "--json").ok()
    one_line(r.returncode, r.stderr, "warning: the best lock (J6=", want=0)
    assert "reaches nothing" in r.stderr and json.loads(r.stdout)["best_reaches_nothing"] is True


def test_progress_lines_off_a_terminal(monkeypatch, capsys):
    import lmjx.runtime.progress as progress

    monkeypatch.setattr(progress, "LINE_SECONDS", 0.0)
    monkeypatch.delenv("LMJX_PROGRESS", raising=False)
    bar = progress.Progress(total=4, desc="reach case2", unit="IK")
    bar.update(1)
    bar.update(3)
    bar.close()
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 2 and lines[-1].startswith("reach case2: 4/4 IK (100 %)"), lines
    monkeypatch.setenv("LMJX_PROGRESS", "0")
    bar = progress.Progress(total=4, desc="reach case2")
    bar.update(4)
    bar.close()
    assert capsys.readouterr().err == ""
    assert "LMJX_PROGRESS=0" in cli("--help").stdout


def test_plan_says_robot_time_is_simulated_and_evaluate_says_it_resumed(small_map, tmp_path):
    r = cli("plan", "--map", small_map, "--scenario", "1", "--asm", "random", "--max-actions", "1").ok()
    assert "robot time" in r.stdout and "(simulated execution)" in r.stdout and "execution " not in r.stdout
    args = ("evaluate", "--failures", "case2", "--scenarios", "1", "--asms", "random", "--trials", "1",
            "--max-actions", "1", "--maps", small_map.parent, "--out", tmp_path)  # fmt: skip
    assert "resuming" not in cli(*args).ok().stderr
    assert f"resuming: 1 of 1 trials already in {tmp_path / 'results.json'}" in cli(*args).ok().stderr


def test_evaluation_in_parts_and_replayed(plan_map, tmp_path):
    """A run split in parts (--part K/N) makes the whole run's trials; replaying their recorded
    edges (benchmarks/recount_contacts.py) executes the same actions again, and a record that
    differs from what its edges do is caught."""
    # the hard set (its tasks stay as they are; the paper set's change with each calibration: its
    # seventh made base 4's first trial reach the goal in one action), seed base 4: on this map
    # the first trial spends its 2 actions, the second finds no feasible action at its first
    # decision, every edge tested blocked at its start or unusable (the map's edges alone:
    # turned copies give it actions)
    args = ("evaluate", "--failures", "case2", "--scenarios", "1", "--asms", "random", "--trials", "2",
            "--max-actions", "2", "--seed", "4", "--tasks", "hard", "--maps", plan_map.parent,
            "--set", "turn_edges=false", "--out")  # fmt: skip
    cli(*args, tmp_path / "whole").ok()
    cli(*args, tmp_path / "parts", "--part", "2/2").ok()
    assert [r["seed"] for r in trials_of(tmp_path / "parts" / "results.json")] == [401001]
    cli(*args, tmp_path / "parts", "--part", "1/2").ok()
    split = trials_of(tmp_path / "parts" / "results.json")
    whole = trials_of(tmp_path / "whole" / "results.json")
    edges = [[s["edge"] for s in r["steps"]] for r in whole]
    assert [r["seed"] for r in split] == [401000, 401001] and all(edges), edges  # every trial acted
    assert [[s["edge"] for s in r["steps"]] for r in split] == edges
    # a trial that ended with no action says why, edge by edge over the target ("no feasible
    # action": none of them lacked only a transit)
    ended = {r["seed"]: r.get("no_action") for r in whole}
    assert ended[401000] is None and whole[0]["end"] == "budget", whole[0]["end"]
    why = ended[401001]
    assert whole[1]["end"] == "no feasible action" and why["tested"] > 0 and why["no_transit"] == 0, (whole[1], why)
    assert why["tested"] == why["start_blocked"] + why["edge_unusable"] + why["no_transit"], why
    for bad in ("3/2", "half"):
        cli(*args, tmp_path / "bad", "--part", bad).one_line_error("--part")
    recount_contacts = benchmark_module("recount_contacts")
    split[1]["steps"][0]["target_moved_m"] += 0.01
    replayed = recount_contacts.replay(split, plan_map.parent, lambda line: None)
    assert [[st["same"] for st in t["steps"]] for t in replayed] == [[True] * len(edges[0]), [False] * len(edges[1])]
    assert [st["transit_contacts"] for st in replayed[0]["steps"]] == [s["transit_contacts"] for s in split[0]["steps"]]


def test_evaluation_plots_when_nothing_succeeds(tmp_path):
    """The figures from results where no trial succeeds (and one cell of a single trial): no
    warning (matplotlib's 'No artists with labels' among them), both files written."""
    from lmjx.evaluation.evaluate import plots

    failed = {"success": False, "actions": 30, "execution_s": 50.0}
    records = [
        {"failure": f, "scenario": s, "asm": a, "seed": t, "planning_s": 1.0 + t, **failed}
        for f in ("case1", "case2")
        for s in (1, 2)
        for a in ("random", "greedy")
        for t in range(2 if s == 1 else 1)
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plots(records, tmp_path)
        plots(records[:1], tmp_path)  # one cell, every time equal
    for name in ("bubble.png", "actions.png"):
        assert Path(tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
