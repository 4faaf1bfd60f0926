"""Progress off a terminal: lines that count the real units of work and end at 100 %."""

from __future__ import annotations

import pytest

from lmjx.runtime import progress


def test_a_build_counts_its_edges_to_the_end(monkeypatch, capsys):
    monkeypatch.setenv("LMJX_PROGRESS", "")
    monkeypatch.setattr(progress, "LINE_SECONDS", 0.0)
    bar = progress.Progress(total=10_000, desc="edges case2", unit="edge", steps_per_unit=2)  # (a start, a rollout)
    for _ in range(4):
        bar.update(5_000)
    bar.close()
    lines = capsys.readouterr().err.splitlines()
    assert lines[0].startswith("edges case2: 2,500/10,000 edge (25 %)")
    assert lines[-1].startswith("edges case2: 10,000/10,000 edge (100 %)") and len(lines) == 4


def test_the_preflight_counts_a_busy_machine(monkeypatch, tmp_path):
    """Other work on the cores slows a CPU build: the preflight says so and counts it."""
    from lmjx.edges import preflight as pf

    monkeypatch.setattr(pf, "usable_cores", lambda: 2)
    monkeypatch.setattr(pf.os, "getloadavg", lambda: (0.4, 0.4, 0.4))
    idle = pf.preflight(10_000, tmp_path / "m.h5", 1, "cpu")
    monkeypatch.setattr(pf.os, "getloadavg", lambda: (5.0, 5.0, 5.0))
    busy = pf.preflight(10_000, tmp_path / "m.h5", 1, "cpu")
    assert busy.seconds == pytest.approx(3.5 * idle.seconds)
    assert "busy (load average 5.0 on 2 cores): 3.5x" in busy.lines()[0] and "busy" not in idle.lines()[0]
    gpu = pf.preflight(10_000, tmp_path / "m.h5", 1, "gpu")  # (a GPU's build is not the host cores')
    assert "busy" not in gpu.lines()[0]
