"""The command line: contracts, one-line errors with exit 2, atomic outputs, interrupts."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

ENV = {**os.environ, "JAX_PLATFORMS": "cpu"}


def lmjx(*args, timeout=600):
    return subprocess.run(
        [sys.executable, "-m", "lmjx.cli", *args], capture_output=True, text=True, timeout=timeout, env=ENV
    )


@pytest.mark.parametrize(
    "args, message",
    [
        (["reach", "--failure", "J9=0"], "J9 does not exist"),
        (["reach", "--failure", "J4=0.5"], "outside the joint's limits"),
        (["reach", "--failure", "case2", "--cell", "0"], "--cell"),
        (["reach", "--failure", "case2", "--out", "/proc/nope/map.h5"], "cannot"),
        (["reach", "--failure", "case2", "--out", "/"], "directory"),
        (["reach", "--failure"], "expected one argument"),
        (["reach", "--failure", "none", "--ips", "nose"], "unknown interaction point"),
        (["info", "/nonexistent.h5"], "does not exist"),
        (["lock-search", "--joints", "J8"], "J8"),
        (["bench", "--sizes", "a,b"], "--sizes"),
        (["frobnicate"], "invalid choice"),
    ],
)
def test_bad_input_one_line_exit_2(args, message, tmp_path):
    r = lmjx(*args)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert message in lines[0]
    assert "Traceback" not in r.stderr
    assert r.stdout == ""


def test_reach_json_contract_and_outputs(tmp_path):
    out, png = tmp_path / "m.h5", tmp_path / "m.png"
    r = lmjx("reach", "--failure", "case1", "--cell", "0.1", "--out", str(out), "--png", str(png), "--json")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["failure"] == "case1" and s["cell_m"] == 0.1
    assert set(s["area_m2"]) == {"pm", "npm_pm"}
    assert isinstance(s["seconds"], float) and s["device"].startswith("cpu")
    assert out.stat().st_size > 0 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp files left
    info = lmjx("info", str(out), "--json")
    assert info.returncode == 0, info.stderr
    assert json.loads(info.stdout)["reach"]["area_m2"] == s["area_m2"]
    text = lmjx("info", str(out))
    assert "case1" in text.stdout


def test_interrupt_leaves_no_file(tmp_path):
    out = tmp_path / "map.h5"
    p = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "lmjx.cli",
            "reach",
            "--failure",
            "case2",
            "--cell",
            "0.005",
            "--restarts",
            "32",
            "--out",
            str(out),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
    )
    time.sleep(8)  # minutes of work (48,000 cells x 32 restarts): it is surely still running
    assert p.poll() is None, "the map finished before it could be interrupted"
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_help_explains():
    r = lmjx("reach", "--help")
    assert r.returncode == 0
    for word in ("--failure", "case2", "J2=0.3,J4=-1.5", "--out", "--png", "--json"):
        assert word in r.stdout


def test_bench_quick_runs(tmp_path):
    out = tmp_path / "bench.json"
    r = lmjx("bench", "--quick", "--repeats", "1", "--out", str(out), timeout=900)
    assert r.returncode == 0, r.stderr
    rep = json.loads(out.read_text())
    assert rep["ik"][0]["solve_per_s"] > 0 and rep["maps"][0]["seconds"] > 0
    assert "pybullet" in rep and "pytorch_kinematics" in rep
    assert "lmjx IK" in r.stdout


def test_build_map_bad_input():
    # (Ctrl-C during a build: tests/test_edgestream.py)
    for args, message in (
        (["build-map", "--failure", "J9=0"], "J9 does not exist"),
        (["build-map", "--failure", "case2", "--edges", "0"], "--edges"),
        (["build-map", "--failure", "case2", "--out", "/proc/x/map.h5"], "cannot"),
    ):
        r = lmjx(*args)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and message in r.stderr, r.stderr


@pytest.fixture(scope="module")
def small_map_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("info") / "m.h5"
    r = lmjx("reach", "--failure", "none", "--cell", "0.2", "--out", str(path))
    assert r.returncode == 0, r.stderr
    return path


@pytest.mark.parametrize("kind", ["truncated", "not_hdf5", "schema", "model"])
def test_info_refuses_bad_files(tmp_path, small_map_file, kind):
    import shutil

    import h5py

    path = tmp_path / "m.h5"
    shutil.copy(small_map_file, path)
    if kind == "truncated":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 3])
    elif kind == "not_hdf5":
        path.write_text("hello")
    else:
        with h5py.File(path, "a") as f:
            if kind == "schema":
                f.attrs["schema_version"] = 7
            else:
                f.attrs["robot_model_hash"] = "f" * 64
    r = lmjx("info", str(path))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr
