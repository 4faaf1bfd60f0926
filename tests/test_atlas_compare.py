"""`lmjx atlas --compare` (lmjx/reach/atlas_compare.py) on synthetic atlases whose outcomes are
known by construction: the counts, shares and medians, the page's generated block between
its markers (the prose around it kept), the figure.  No kernel runs here; the CLI path on a
real (tiny) atlas is in tests/test_atlas.py."""

from __future__ import annotations

import numpy as np
import pytest

from lmjx.errors import ConfigError
from lmjx.reach.atlas import AtlasConfig, AtlasState, read_atlas, write_atlas
from lmjx.reach.atlas_compare import BEGIN, END, arm_survival, compare_markdown, write_page
from lmjx.reach.reachability import NPM, PM, UNREACHABLE, ReachConfig

CELL = 0.5  # 2 x 2 cells of 0.25 m^2


def _atlas(robot: str, maps: list[tuple[int, int, int]], sizes: list[int]) -> AtlasState:
    """One map per (PM cells, NPM-only cells, size): labels with that many cells of each."""
    config = AtlasConfig(angles=2, reach=ReachConfig(cell=CELL, x_range=(0.0, 1.0), y_range=(0.0, 1.0)))
    n = len(maps)
    labels = np.full((n, 2, 2), UNREACHABLE, np.int8)
    for i, (pm, npm, _) in enumerate(maps):
        flat = labels[i].reshape(-1)
        flat[:pm] = PM
        flat[pm : pm + npm] = NPM
    joints = np.full((n, 3), -1, np.int8)
    for i, s in enumerate(sizes):
        joints[i, :s] = np.arange(1, s + 1)
    angles = np.where(joints > 0, 0.1, np.nan)
    return AtlasState(
        config, joints, angles, np.array([0.25, 0.75]), np.array([0.25, 0.75]), labels, labels.copy(),
        np.ones(n, bool), "hash", robot,
    )  # fmt: skip


# (PM cells, NPM-only cells) per lock: 2 keep a grasp, 2 are rescued by NPM, 1 is dead
MAPS = [(4, 0, 2), (1, 2, 2), (0, 2, 3), (0, 1, 3), (0, 0, 3)]


def test_counts_shares_and_medians_by_construction(tmp_path):
    st = _atlas("arm", MAPS, [m[2] for m in MAPS])
    write_atlas(tmp_path / "a.h5", st)  # through the file, as the CLI reads it
    a = arm_survival(read_atlas(tmp_path / "a.h5"), {"pm": 1.0, "npm_pm": 1.0}, joints=6)
    assert (a.all.locks, a.all.pm_zero, a.all.rescued, a.all.dead) == (5, 3, 2, 1)
    assert a.all.share(a.all.rescued) == pytest.approx(0.4)
    # PM areas 1.0, 0.25, 0, 0, 0 (median 0); NPM+PM 1.0, 0.75, 0.5, 0.25, 0 (median 0.5)
    assert a.all.median_pm_kept == 0.0 and a.all.median_npm_pm_kept == pytest.approx(0.5)
    two, three = a.by_size[2], a.by_size[3]
    assert (two.locks, two.pm_zero, three.locks, three.pm_zero, three.rescued, three.dead) == (2, 0, 3, 3, 2, 1)
    assert two.median_npm_pm_kept == pytest.approx(0.875) and three.median_npm_pm_kept == pytest.approx(0.25)
    np.testing.assert_allclose(a.npm_pm_kept, [1.0, 0.75, 0.5, 0.25, 0.0])
    assert a.plane == pytest.approx(1.0) and a.cell == CELL


def test_page_block_between_markers_keeps_the_prose(tmp_path):
    arms = [
        arm_survival(_atlas("first", MAPS, [m[2] for m in MAPS]), {"pm": 1.0, "npm_pm": 1.0}, 7),
        arm_survival(_atlas("second", MAPS[:2], [2, 2]), {"pm": 0.5, "npm_pm": 1.0}, 6),
    ]
    md = tmp_path / "ARMS.md"
    md.write_text(f"# Arms\n\nprose before\n\n{BEGIN}\nold table\n{END}\n\nprose after\n")
    png = write_page(md, arms, {"third": "no atlas at `x.h5`"})
    text = md.read_text()
    assert text.startswith("# Arms\n\nprose before\n\n") and text.endswith(f"{END}\n\nprose after\n")
    assert "old table" not in text and text.count(BEGIN) == 1
    assert "| first | 7 | 1.000 / 1.000 | 5 | 3 (60 %) | 2 (40 %) | 1 (20 %) | 0 % / 50 % |" in text
    assert "| second | 6 | 0.500 / 1.000 | 2 | 0 (0 %) | 0 (0 %) | 0 (0 %) | 125 % / 88 % |" in text
    assert "- third: no atlas at `x.h5`" in text and "![arms](img/arms.png)" in text
    assert png == tmp_path / "img" / "arms.png" and png.read_bytes()[:4] == b"\x89PNG"
    # no arms at all: the missing ones are listed, no figure
    assert "![arms]" not in compare_markdown([], {"x": "y"}, None)


def test_incomplete_atlas_is_refused():
    st = _atlas("arm", MAPS, [m[2] for m in MAPS])
    st.done[1] = False
    with pytest.raises(ConfigError, match="incomplete"):
        arm_survival(st, {"pm": 1.0, "npm_pm": 1.0}, 6)
