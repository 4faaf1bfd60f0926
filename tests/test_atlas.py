"""The failure atlas: the masked IK program against the per-failure one (the Reach-Ability
map's), sharded and multi-process runs against a single-device run, and a killed run
resumed; on the four-joint test arm (tests/data/tiny_arm.xml), whose programs compile
several times faster than the Panda's."""

from __future__ import annotations

import json
import signal
import socket
from pathlib import Path

import numpy as np
import pytest
from conftest import TINY_ARM, TINY_ATLAS, Collected, cli, cli_process, finish, ik_batch, random_configs, wait_for

from lmjx.model.failure import parse_failure
from lmjx.reach.atlas import AtlasConfig, entries, expected_maps, lock_angles, read_atlas, same_content
from lmjx.reach.ik_batch import IKBatch
from lmjx.reach.reachability import ReachConfig

# a small atlas of the four-joint test arm (its program compiles several times faster than the
# Panda's): 6 pairs x 2 x 2 angles, 4 x 5 cells, 4 attempts of 2 restarts (conftest.TINY_ATLAS)
TINY = list(TINY_ATLAS)
MAPS = 24


def _problems(robot, f, sites, n, seed):
    """Half random targets on the task plane, half where a site is at a random configuration
    with the locks applied (reachable by construction, position only)."""
    import mujoco

    rng = np.random.default_rng(seed)
    tgt = np.concatenate([rng.uniform([0.2, -0.5], [0.8, 0.5], (n, 2)), np.full((n, 2), 0.025)], axis=1)
    site = rng.integers(0, 3, n).astype(np.int32)
    pm = site == 0
    m, d = robot.mj, mujoco.MjData(robot.mj)
    qs = random_configs(robot, n, seed + 7)
    for j, a in f.locked:
        qs[:, j - 1] = a
    for i in range(0, n, 2):
        d.qpos[:] = qs[i]
        mujoco.mj_kinematics(m, d)
        site[i] = 1 + i % 2
        pm[i] = False
        p = d.site_xpos[sites[site[i]]]
        tgt[i] = [p[0], p[1], p[2], p[2]]
    return tgt.astype(np.float32), site, pm


def _both(robot, spec, n, seed):
    """The failure's own program (the Reach-Ability map's) and the masked one, with the same
    sites, settings and launch size, on the same problems (sites: the TCP, hand, wrist)."""
    f = parse_failure(spec, robot)
    static_batch = ik_batch(robot, f)
    tgt, site, pm = _problems(robot, f, static_batch.sites, n, seed)
    q0 = random_configs(robot, n, seed + 1).astype(np.float32)
    free = list(f.free())
    static = static_batch.solve(tgt, site, pm, q0[:, free])
    mask = np.ones((n, robot.nq), np.float32)
    q0m = q0.copy()
    for j, a in f.locked:
        mask[:, j - 1] = 0
        q0m[:, j - 1] = a
    s = static_batch
    masked = IKBatch(robot, f, s.sites, s.settings, s.chunk, masked=True).solve(tgt, site, pm, q0m, mask=mask)
    return f, static, masked


@pytest.fixture(scope="module")
def tiny_arm():
    """The masked program is the same code for any arm: the test arm's (its programs compile
    several times faster than the Panda's)."""
    from lmjx.model.robot import load_robot

    return load_robot(str(TINY_ARM))


def test_masked_program_equals_the_failures_own(tiny_arm):
    # Locking the first joints leaves the table-row grouping of the kernel unchanged, so the
    # masked iteration is the same arithmetic as the per-failure program's.
    # (float32 rounding differs with XLA's fusion, and 48 nonlinear iterations amplify it)
    _, static, masked = _both(tiny_arm, "J1=0.4,J2=-0.3", 256, 0)
    np.testing.assert_array_equal(masked["q"][:, :2], np.tile([0.4, -0.3], (256, 1)).astype(np.float32))
    diff = np.abs(masked["q"] - static["q"]).max(axis=1)
    assert np.median(diff) < 1e-5 and np.quantile(diff, 0.95) < 2e-3, np.quantile(diff, [0.5, 0.95])
    assert (masked["ok"] == static["ok"]).mean() >= 0.98 and 0.1 < static["ok"].mean() < 0.95


def test_masked_program_locks_exactly_and_agrees_statistically(tiny_arm):
    # Locking the last joint merges table rows in the per-failure program; the masked one
    # keeps one row per link: the same problem, solved slightly differently.
    _, static, masked = _both(tiny_arm, "J4=0.5", 1024, 1)
    assert (masked["q"][:, 3] == np.float32(0.5)).all()
    agree = (masked["ok"] == static["ok"]).mean()
    assert agree > 0.93, agree
    assert abs(masked["ok"].mean() - static["ok"].mean()) < 0.03


def test_entries_count_and_angles(robot):
    cfg = AtlasConfig(angles=3)
    joints, angles = entries(robot, cfg)
    assert len(joints) == expected_maps((2, 3), 3, robot.nq) == 21 * 9 + 35 * 27 == 1134
    table = lock_angles(robot, 3, 0)
    width = (robot.upper - robot.lower) / 3
    for k in range(3):  # one angle in each third of every joint's range
        assert np.all((table[:, k] >= robot.lower + k * width) & (table[:, k] <= robot.lower + (k + 1) * width))
    keys = {(tuple(j), tuple(np.round(a, 9))) for j, a in zip(joints.tolist(), angles.tolist(), strict=True)}
    assert len(keys) == 1134  # no map twice


@pytest.fixture(scope="module")
def single(tiny_atlas):
    return tiny_atlas


def test_single_device_atlas_is_complete(single):
    st = read_atlas(single)
    assert st.n == MAPS and st.done.all()
    a = st.areas()
    assert np.all(a["npm_pm"] >= a["pm"]) and a["npm_pm"].max() > 0


def test_four_host_devices_give_the_same_atlas(single, tmp_path):
    out = tmp_path / "four.h5"
    four = {"XLA_FLAGS": "--xla_force_host_platform_device_count=4"}
    p = cli_process("atlas", *TINY, "--out", out, "--json", env=four)
    s = json.loads(finish(p).ok().stdout)
    assert s["devices"] == 4
    assert same_content(single, out) == []


def test_two_processes_on_loopback_give_the_same_atlas(single, tmp_path):
    with socket.socket() as sk:
        sk.bind(("127.0.0.1", 0))
        port = sk.getsockname()[1]
    common = ["atlas", *TINY, "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2", "--json"]
    procs = [cli_process(*common, "--out", tmp_path / f"p{i}.h5", "--process-id", i) for i in range(2)]
    runs = [finish(p) for p in procs]
    assert all(r.returncode == 0 for r in runs), [r.stderr[-2000:] for r in runs]
    text = runs[0].stdout
    assert json.loads(text[text.index("{\n") :])["processes"] == 2  # (gloo may log a line before)
    assert same_content(single, tmp_path / "p0.h5") == []
    assert not (tmp_path / "p1.h5").exists()  # only process 0 writes


def test_killed_run_resumes_to_the_same_file(single, tmp_path):
    out = tmp_path / "resumed.h5"
    partial = Path(str(out) + ".partial")
    p = cli_process("atlas", *TINY, "--no-shard", "--out", out)
    err = Collected(p.stderr)
    wait_for(partial.exists, p, "the partial atlas")
    p.send_signal(signal.SIGKILL)
    p.wait(timeout=60)
    err.finish()
    assert partial.exists() and not out.exists(), "the run finished before it could be killed"
    done_before = int(read_atlas(partial).done.sum())
    assert 0 < done_before < MAPS
    r = cli("atlas", *TINY, "--no-shard", "--out", out, "--json").ok()
    assert f"{done_before} of {MAPS} maps already computed" in r.stderr  # the resumed run says so
    s = json.loads(r.stdout)
    assert s["maps_this_run"] == MAPS - done_before  # nothing computed twice
    assert out.exists() and not partial.exists()
    assert same_content(single, out) == []


def test_bad_input_one_line_exit_2(tmp_path):
    for args, msg in (
        (["--joints", "4"], "locked joints"),
        (["--joints", "x"], "--joints"),
        (["--coordinator", "nohost", "--num-processes", "2"], "host:port"),
    ):
        r = cli("atlas", *args, "--out", tmp_path / "a.h5")
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and msg in r.stderr, r.stderr


def test_other_parameters_are_refused(single, tmp_path):
    other = tmp_path / "other.h5"
    other.write_bytes(Path(single).read_bytes())
    r = cli("atlas", *TINY, "--seed", "5", "--out", other)
    assert r.returncode == 2 and "other parameters" in r.stderr, r.stderr


def test_plain_reader_reads_the_atlas(single):
    import h5py

    with h5py.File(single, "r") as f:
        assert f.attrs["schema"] == "lmjx-atlas" and f["labels"].shape[0] == MAPS
        assert np.isfinite(f["area_npm_pm_m2"][...]).all()
        assert ReachConfig(cell=0.2).cell == f.attrs["cell_m"]


def test_compare_reads_the_atlas_and_writes_the_page(single, tmp_path):
    """`lmjx atlas --compare`: the tiny arm's atlas, its no-failure map computed with the
    atlas's parameters (the logic itself: tests/test_atlas_compare.py)."""
    md = tmp_path / "ARMS.md"
    s = json.loads(
        cli("atlas", "--compare", f"{TINY_ARM}={single}", "--compare", "ur5e=nowhere.h5", "--summary", md, "--json")
        .ok()
        .stdout
    )
    st = read_atlas(single)
    a = st.areas()
    (row,) = s["arms"]
    assert row["locks"] == MAPS and row["pm_zero"] == int((a["pm"] == 0).sum())
    assert row["rescued_by_npm"] == int(((a["pm"] == 0) & (a["npm_pm"] > 0)).sum())
    assert row["none_m2"]["npm_pm"] > 0 and row["none_m2"]["npm_pm"] >= row["none_m2"]["pm"]
    assert list(s["missing"]) == ["ur5e"] and (tmp_path / "img" / "arms.png").exists()
    assert "| " + st.robot + " | 4 |" in md.read_text()
