"""`lmjx bench --sections ik`: lmjx's IK beside its baselines, PyBullet's and
pytorch_kinematics' (a file of its own: its programs compile for a minute or more in a fresh
cache, beside the other files' tests)."""

from __future__ import annotations

import json
import math

from conftest import cli


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
