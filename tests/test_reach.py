"""The Reach-Ability map: labels, smoothing, determinism, and every accepted solution
re-checked in C MuJoCo; Table I's relations on the default map."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from lmjx.errors import ConfigError
from lmjx.reach.reachability import NPM, PM, UNREACHABLE, ReachConfig, reach_map, smooth_labels

COARSE = ReachConfig(cell=0.05)


def test_smoothing_fills_isolated_holes_only():
    lab = np.full((7, 7), PM, np.int8)
    lab[3, 3] = UNREACHABLE  # a hole inside PM
    lab[0, :] = UNREACHABLE  # an edge row: not a hole
    lab[6, 6] = NPM
    out = smooth_labels(lab, 6)
    assert out[3, 3] == PM
    assert (out[0, :] == UNREACHABLE).all()
    assert np.all(out >= lab)  # never lowers a cell
    lone = np.zeros((5, 5), np.int8)
    lone[2, 2] = PM  # an isolated reachable cell stays (smoothing only fills)
    assert np.array_equal(smooth_labels(lone), lone)


def _check_map_in_mujoco(robot, res):
    m = robot.mj
    d = mujoco.MjData(m)
    locked = [j - 1 for j in res.failure.locked_joints]
    qf = res.failure.q_fixed()
    n = 0
    for iy, ix in zip(*np.nonzero(res.labels), strict=True):
        q = res.q[iy, ix].astype(np.float64)
        assert np.all(q[locked] == qf[locked].astype(np.float32))
        assert np.all(q >= robot.lower - 1e-6) and np.all(q <= robot.upper + 1e-6)
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        assert d.ncon == 0
        x, y, zlo, zhi = res.target[iy, ix]
        p = d.site_xpos[res.site[iy, ix]]
        assert np.hypot(np.hypot(p[0] - x, p[1] - y), p[2] - np.clip(p[2], zlo, zhi)) <= 0.002 + 1e-5
        # the solved target lies in the cell
        assert abs(x - res.xs[ix]) <= res.config.cell / 2 + 1e-6 and abs(y - res.ys[iy]) <= res.config.cell / 2 + 1e-6
        if res.labels[iy, ix] == PM:
            assert res.site[iy, ix] == robot.tcp_site
            assert d.site_xmat[robot.tcp_site].reshape(3, 3)[2, 2] <= 1e-6
        else:
            assert robot.site_names[res.site[iy, ix]].startswith("ip_")
        n += 1
    return n


@pytest.mark.parametrize("spec", ["none", "case1", "case2"])
def test_coarse_map_solutions_verified_in_mujoco(robot, coarse, spec):
    res = coarse[spec]
    assert res.labels.shape == (len(res.ys), len(res.xs)) == (24, 20)
    assert _check_map_in_mujoco(robot, res) > 0
    assert np.all(np.isnan(res.q[res.labels == UNREACHABLE]))
    s = res.summary()
    assert set(s) >= {"failure", "cell_m", "area_m2", "seconds", "device"}
    assert set(s["area_m2"]) == {"pm", "npm_pm"}


def test_same_seed_same_map_and_strategies_agree(robot, coarse):
    a = coarse["case1"]
    b = reach_map("case1", COARSE, robot=robot)
    assert np.array_equal(a.labels, b.labels) and np.array_equal(a.q, b.q, equal_nan=True)
    c = reach_map("case1", dataclasses.replace(COARSE, strategy="batch"), robot=robot)
    assert (a.labels == c.labels).mean() >= 0.99
    d = reach_map("case1", dataclasses.replace(COARSE, seed=1), robot=robot)
    assert not np.array_equal(a.q, d.q, equal_nan=True)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(cell=0.0),
        dict(cell=-1),
        dict(attempts=1),
        dict(restarts=0),
        dict(interaction_points=("nose",)),
        dict(x_range=(0.5, 0.5)),
        dict(strategy="fast"),
    ],
)
def test_bad_config_is_a_config_error(robot, kwargs):
    with pytest.raises(ConfigError):
        reach_map("none", ReachConfig(**kwargs), robot=robot)


def test_table1_relations(robot, table1):
    """Paper Table I's relations on the default 2 cm map (the figures are in README.md)."""
    a = {f: table1[f].areas(True) for f in ("none", "case1", "case2")}
    assert a["case2"]["pm"] <= 0.05 * a["none"]["pm"]
    assert a["case1"]["pm"] < a["none"]["pm"]
    for f in ("case1", "case2"):
        assert a[f]["npm_pm"] >= a[f]["pm"] + 0.05  # NPM adds at least 0.05 m^2
    assert a["none"]["npm_pm"] >= a["none"]["pm"]


def _readme_table1(
    heading: str = "## Table I, reproduced", column: int = 3, page: str = "docs/DETAILS.md"
) -> dict[tuple[str, str], float]:
    """A Table I of docs/DETAILS.md (or of `page`; the one under `heading`): (failure, 'pm' |
    'npm_pm') -> the area [m^2] its `column` states."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / page).read_text()
    section = text[text.index(heading) + len(heading) :].split("\n## ", 1)[0].split("\n### ", 1)[0]
    out, failure = {}, None
    for line in section.splitlines():
        cols = [c.strip().strip("*") for c in line.strip().strip("|").split("|")]
        if len(cols) != 6 or cols[1] not in ("PM", "NPM+PM"):
            continue
        failure = cols[0].split(" (")[0].replace(" ", "") or failure
        out[(failure, "pm" if cols[1] == "PM" else "npm_pm")] = float(cols[column])
    return out


def test_table1_figures_are_the_readmes(robot, table1):
    """Every area of README's Table I is what the code computes today (to its 3 decimals)."""
    stated = _readme_table1()
    assert len(stated) == 6
    for (failure, kind), value in stated.items():
        assert round(table1[failure].areas(True)[kind], 3) == value, (failure, kind)
    # the UR5e's table beside it repeats the Panda's figures
    beside = _readme_table1("### The same table for the UR5e", column=2)
    assert beside == {k: v for k, v in stated.items()}
    # and the README's Table I states the same
    assert _readme_table1("**Table I**", page="README.md") == stated


def test_ur5e_table1_figures_are_the_readmes(ur5e, table1_ur5e):
    """Every area of the README's UR5e column is what the code computes today (3 decimals),
    and every accepted solution of those maps holds in C MuJoCo."""
    stated = _readme_table1("### The same table for the UR5e", column=3)
    assert len(stated) == 6
    for (failure, kind), value in stated.items():
        assert round(table1_ur5e[failure].areas(True)[kind], 3) == value, (failure, kind)
    for f in ("none", "case1", "case2"):
        assert _check_map_in_mujoco(ur5e, table1_ur5e[f]) > 0


def test_default_map_solutions_verified_in_mujoco(robot, table1):
    """Every accepted solution of the default maps: no contact in C MuJoCo (in particular no
    robot-table penetration), locked joints exact, limits, target within 2 mm."""
    for f in ("none", "case1", "case2"):
        _check_map_in_mujoco(robot, table1[f])
