"""Progress off a terminal: lines that count the real units of work and end at 100 %."""

from __future__ import annotations

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
