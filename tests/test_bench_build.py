"""`lmjx bench --sections build`: the user's build-map in a fresh process, its stages, the
wall / kernel ratio and the preflight's error; the preflight's per-stage estimate.

The timed build is the four-joint test arm's (conftest's TINY_MAP, fewer edges): its programs
are in the run's cache (the `tiny_map` fixture compiled them), so nothing new compiles."""

from __future__ import annotations

import dataclasses

import pytest
from conftest import TINY_MAP

from lmjx.bench.bench import parse_sections
from lmjx.bench.build import STAGES, build_row, print_build, run_build
from lmjx.edges.preflight import RATES, Work, stage_seconds


def test_the_build_section_times_the_users_command(tiny_map, capsys):
    args = [str(a) for a in TINY_MAP]
    args[args.index("--edges") + 1] = "400"
    row = run_build(args)
    assert row["edges"] == 400 and row["device"] == "cpu" and 0 < row["edges_valid"] <= 400
    stages = row["stages_s"]
    assert set(stages) == set(STAGES)
    # the stages (other included) add up to the process's wall time
    assert sum(stages.values()) == pytest.approx(row["wall_s"], abs=0.01)
    assert stages["ik"] > 0 and stages["rollout"] > 0 and stages["reach"] > 0 and stages["push"] >= 0
    assert 0 < row["build_s"] < row["wall_s"]
    kernel = stages["ik"] + stages["rollout"] + stages["index"] + stages["push"]
    assert row["kernel_s"] == pytest.approx(kernel, abs=0.01)
    assert row["wall_over_kernel"] == pytest.approx(row["wall_s"] / row["kernel_s"], rel=0.01)
    assert row["preflight_s"] > 0 and set(row["preflight_stages_s"]) == {"startup", *STAGES[:-1]}
    err = 100 * (row["preflight_s"] - row["wall_s"]) / row["wall_s"]
    # (from the wall time rounded to the millisecond: off by a few tenths where the estimate is several times it)
    assert row["preflight_error_pct"] == pytest.approx(err, rel=1e-3, abs=0.1)
    assert "per-stage rates" in row["preflight_basis"]
    print_build({"failure": "J4=0.5", "rows": [row]})
    out = capsys.readouterr().out.splitlines()
    assert out[1].split() == ["edges", "wall", *STAGES, "kernels", "wall/k", "preflight"]
    assert out[2].split()[:2] == ["400", f"{row['wall_s']:.1f}"] and f"({row['preflight_error_pct']:+.0f}%)" in out[2]


def test_build_row_arithmetic():
    e = {"edges_sampled": 10, "edges_valid": 4, "states": 50, "device": "cpu", "devices": 1, "reach_seconds": 5.0,
         "ik_seconds": 2.0, "rollout_seconds": 3.0, "index": {"seconds": 1.0}, "push_seconds": 0.5,
         "write_seconds": 0.25, "finish_seconds": 0.25, "writer_timing": {"digest": 0.5, "replace": 0.0},
         "build_seconds": 18.0, "preflight": {"seconds": 24.0, "stages": {}, "basis": "per-stage rates"}}  # fmt: skip
    s = {"failure": "case2", "edges": e, "compile_seconds": 4.0, "compile_seconds_by_stage": {"reach": 1.0}}
    row = build_row(s, 20.0)
    assert row["stages_s"] == {"reach": 4.0, "ik": 2.0, "rollout": 3.0, "index": 1.0, "push": 0.5, "write": 1.0,
                               "compile": 4.0, "other": 4.5}  # fmt: skip
    assert row["kernel_s"] == 6.5 and row["wall_over_kernel"] == round(20 / 6.5, 2)
    assert row["preflight_error_pct"] == 20.0
    assert parse_sections("build") == {"build"}


def test_the_preflight_sums_per_stage_rates(monkeypatch):
    work = Work.of(1000, cells=3000, attempts=10, restarts=8, ik_restarts=8, steps=100)
    cpu = RATES["cpu"]
    cold = stage_seconds(work, "cpu", 1, cpu.cores, {})
    assert cold["rollout"] == pytest.approx(work.edge_steps / cpu.edge_steps_per_s)
    assert cold["reach"] == pytest.approx(240_000 / cpu.reach_problems_per_s)
    assert cold["compile"] == pytest.approx(sum(cpu.compile_s.values()))
    warm = stage_seconds(work, "cpu", 1, cpu.cores, dict.fromkeys(cpu.compile_s, True))
    assert warm["compile"] == pytest.approx(sum(cpu.cached_s.values())) and warm["compile"] < cold["compile"]
    # twice the cores: the kernels' stages take half; two GPUs: the edges' stages gain `device_gain`
    double = stage_seconds(work, "cpu", 1, 2 * cpu.cores, {})
    assert double["rollout"] == pytest.approx(cold["rollout"] / 2) and double["startup"] == cold["startup"]
    # several chunks: the CPU's chunk threads run side by side
    many = Work.of(40_000, cells=3000, attempts=10, restarts=8, ik_restarts=8, steps=100, chunk=16_384)
    assert many.chunks == 3
    side = stage_seconds(many, "cpu", 1, cpu.cores, {})
    assert side["rollout"] == pytest.approx(cpu.overlap * many.edge_steps / cpu.edge_steps_per_s)
    one, two = (stage_seconds(work, "gpu", d, 16, {}) for d in (1, 2))
    assert two["rollout"] == pytest.approx(one["rollout"] / (1 + RATES["gpu"].device_gain))
    assert two["reach"] == one["reach"]
    half = dataclasses.replace(RATES["gpu"], device_gain=0.5)  # a second device adding half a device's rate
    monkeypatch.setitem(RATES, "gpu", half)
    one, three = (stage_seconds(work, "gpu", d, 16, {}) for d in (1, 3))
    assert three["rollout"] == pytest.approx(one["rollout"] / 2) and three["index"] == pytest.approx(one["index"] / 2)
