"""The command line: contracts, one-line errors with exit 2, atomic outputs, interrupts."""

from __future__ import annotations

import json
import math
import shutil
import signal

import pytest
from conftest import Collected, cli, cli_process, wait_for


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
def test_bad_input_one_line_exit_2(args, message):
    cli(*args).one_line_error(message)


def test_reach_json_contract_and_outputs(tmp_path):
    out, png = tmp_path / "m.h5", tmp_path / "m.png"
    r = cli("reach", "--failure", "case1", "--cell", "0.1", "--out", out, "--png", png, "--json").ok()
    s = json.loads(r.stdout)
    assert s["failure"] == "case1" and s["cell_m"] == 0.1
    assert set(s["area_m2"]) == {"pm", "npm_pm"}
    assert isinstance(s["seconds"], float) and s["device"].startswith("cpu")
    assert out.stat().st_size > 0 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp files left
    info = cli("info", out, "--json").ok()
    assert json.loads(info.stdout)["reach"]["area_m2"] == s["area_m2"]
    assert "case1" in cli("info", out).ok().stdout


def test_interrupt_leaves_no_file(tmp_path):
    """Ctrl-C while the map is being computed (minutes of work: 48,000 cells x 32 restarts):
    exit 130, one line, nothing at --out."""
    out = tmp_path / "map.h5"
    p = cli_process("reach", "--failure", "case2", "--cell", "0.005", "--restarts", "32", "--out", out,
                    env={"LMJX_PROGRESS": "1"})  # fmt: skip
    err = Collected(p.stderr)
    wait_for(lambda: "reach case2 attempt 1/10" in err.text, p, "the first progress line")
    p.send_signal(signal.SIGINT)
    p.wait(timeout=120)
    text = err.finish()
    assert p.returncode == 130, text
    assert "interrupted" in text and "Traceback" not in text
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_help_explains():
    r = cli("reach", "--help")
    assert r.returncode == 0
    for word in ("--failure", "case2", "J2=0.3,J4=-1.5", "--out", "--png", "--json"):
        assert word in r.stdout


def test_bench_compares_with_both_baselines(tmp_path):
    """The IK section (the one with the baselines): PyBullet's and pytorch_kinematics' figures
    are there (not skipped) and every ratio is a finite positive number."""
    out = tmp_path / "bench.json"
    r = cli("bench", "--quick", "--sections", "ik", "--sizes", "4096", "--repeats", "1", "--out", out).ok()
    rep = json.loads(out.read_text())
    assert rep["ik"][0]["solve_per_s"] > 0 and rep["ik"][0]["solve_check_per_s"] > 0
    for baseline in ("pybullet", "pytorch_kinematics"):
        assert "skipped" not in rep[baseline], rep[baseline]
        assert rep[baseline]["solve_per_s"] > 0
    assert set(rep["ratios"]) == {"lmjx_vs_pybullet", "lmjx_vs_pytorch_kinematics_same_batch"}
    assert all(math.isfinite(v) and v > 0 for v in rep["ratios"].values()), rep["ratios"]
    assert "lmjx IK" in r.stdout and "PyBullet calculateInverseKinematics" in r.stdout


def test_build_map_bad_input():
    # (Ctrl-C during a build: tests/test_edgestream.py)
    for args, message in (
        (["build-map", "--failure", "J9=0"], "J9 does not exist"),
        (["build-map", "--failure", "case2", "--edges", "0"], "--edges"),
        (["build-map", "--failure", "case2", "--out", "/proc/x/map.h5"], "cannot"),
    ):
        cli(*args).one_line_error(message)


@pytest.mark.parametrize("kind", ["truncated", "not_hdf5", "schema", "model"])
def test_info_refuses_bad_files(tmp_path, small_map, kind):
    import h5py

    path = tmp_path / "m.h5"
    shutil.copy(small_map, path)
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
    r = cli("info", path)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr
