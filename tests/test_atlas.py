"""The failure atlas: the masked IK program against the per-failure one, sharded and
multi-process runs against a single-device run, and a killed run resumed."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import random_configs

from lmjx.atlas import AtlasConfig, entries, expected_maps, lock_angles, read_atlas, same_content
from lmjx.failure import parse_failure
from lmjx.ik_batch import IKBatch
from lmjx.kernels.ik import IKSettings
from lmjx.reach import ReachConfig

SETTINGS = IKSettings(iterations=32)
# a small atlas: 21 pairs x 1 angle, 5 x 6 cells, 4 attempts of 2 restarts
TINY = ["--joints", "2", "--angles", "1", "--cell", "0.2", "--attempts", "4", "--restarts", "2", "--iterations", "16",
        "--group", "3", "--chunk", "128"]  # fmt: skip


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
    f = parse_failure(spec, robot)
    sites = (robot.tcp_site, robot.interaction_points["hand"], robot.interaction_points["wrist"])
    tgt, site, pm = _problems(robot, f, sites, n, seed)
    q0 = random_configs(robot, n, seed + 1).astype(np.float32)
    free = list(f.free())
    static = IKBatch(robot, f, sites, SETTINGS, 256).solve(tgt, site, pm, q0[:, free])
    mask = np.ones((n, 7), np.float32)
    q0m = q0.copy()
    for j, a in f.locked:
        mask[:, j - 1] = 0
        q0m[:, j - 1] = a
    masked = IKBatch(robot, f, sites, SETTINGS, 256, masked=True).solve(tgt, site, pm, q0m, mask=mask)
    return f, static, masked


def test_masked_program_equals_the_failures_own(robot):
    # Locking the first joints leaves the table-row grouping of the kernel unchanged, so the
    # masked iteration is the same arithmetic as the per-failure program's.
    # (float32 rounding differs with XLA's fusion, and 32 nonlinear iterations amplify it)
    _, static, masked = _both(robot, "J1=0.4,J2=-0.3", 256, 0)
    np.testing.assert_array_equal(masked["q"][:, :2], np.tile([0.4, -0.3], (256, 1)).astype(np.float32))
    diff = np.abs(masked["q"] - static["q"]).max(axis=1)
    assert np.median(diff) < 1e-5 and np.quantile(diff, 0.95) < 2e-3, np.quantile(diff, [0.5, 0.95])
    assert (masked["ok"] == static["ok"]).mean() >= 0.98 and 0.1 < static["ok"].mean() < 0.95


def test_masked_program_locks_exactly_and_agrees_statistically(robot):
    # Locking the last joints merges table rows in the per-failure program; the masked one
    # keeps one row per link: the same problem, solved slightly differently.
    _, static, masked = _both(robot, "J6=0.935,J7=-0.7193", 1024, 1)
    assert (masked["q"][:, 5] == np.float32(0.935)).all() and (masked["q"][:, 6] == np.float32(-0.7193)).all()
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


def _lmjx(args, env=None, **kw):
    e = dict(os.environ, JAX_PLATFORMS="cpu")
    e.update(env or {})
    return subprocess.Popen([sys.executable, "-m", "lmjx.cli", *args], env=e, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)  # fmt: skip


def _run(args, env=None, timeout=600):
    p = _lmjx(args, env)
    out, err = p.communicate(timeout=timeout)
    assert p.returncode == 0, err
    return out


@pytest.fixture(scope="module")
def single(tmp_path_factory):
    path = tmp_path_factory.mktemp("atlas") / "single.h5"
    _run(["atlas", *TINY, "--no-shard", "--out", str(path), "--json"])
    return path


def test_single_device_atlas_is_complete(single, robot):
    st = read_atlas(single, robot)
    assert st.n == 21 and st.done.all()
    a = st.areas()
    assert np.all(a["npm_pm"] >= a["pm"]) and a["npm_pm"].max() > 0


def test_four_host_devices_give_the_same_atlas(single, tmp_path):
    out = tmp_path / "four.h5"
    s = json.loads(_run(["atlas", *TINY, "--out", str(out), "--json"],
                        env={"XLA_FLAGS": "--xla_force_host_platform_device_count=4"}))  # fmt: skip
    assert s["devices"] == 4
    assert same_content(single, out) == []


def test_two_processes_on_loopback_give_the_same_atlas(single, tmp_path):
    with socket.socket() as sk:
        sk.bind(("127.0.0.1", 0))
        port = sk.getsockname()[1]
    common = ["atlas", *TINY, "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2", "--json"]
    procs = [_lmjx([*common, "--out", str(tmp_path / f"p{i}.h5"), "--process-id", str(i)]) for i in range(2)]
    outs = [p.communicate(timeout=600) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1][-2000:] for o in outs]
    text = outs[0][0]
    assert json.loads(text[text.index("{\n") :])["processes"] == 2  # (gloo may log a line before)
    assert same_content(single, tmp_path / "p0.h5") == []
    assert not (tmp_path / "p1.h5").exists()  # only process 0 writes


def test_killed_run_resumes_to_the_same_file(single, tmp_path):
    out = tmp_path / "resumed.h5"
    partial = Path(str(out) + ".partial")
    p = _lmjx(["atlas", *TINY, "--no-shard", "--out", str(out)])
    t0 = time.time()
    while not partial.exists() and p.poll() is None and time.time() - t0 < 600:
        time.sleep(0.05)
    p.send_signal(signal.SIGKILL)
    p.communicate()
    assert partial.exists() and not out.exists(), "the run finished before it could be killed"
    done_before = int(read_atlas(partial).done.sum())
    assert 0 < done_before < 21
    s = json.loads(_run(["atlas", *TINY, "--no-shard", "--out", str(out), "--json"]))
    assert s["maps_this_run"] == 21 - done_before  # nothing computed twice
    assert out.exists() and not partial.exists()
    assert same_content(single, out) == []


def test_bad_input_one_line_exit_2(tmp_path):
    for args, msg in (
        (["--joints", "4"], "locked joints"),
        (["--joints", "x"], "--joints"),
        (["--coordinator", "nohost", "--num-processes", "2"], "host:port"),
    ):
        p = _lmjx(["atlas", *args, "--out", str(tmp_path / "a.h5")])
        _, err = p.communicate(timeout=120)
        assert p.returncode == 2 and len(err.strip().splitlines()) == 1 and msg in err, err


def test_other_parameters_are_refused(single, tmp_path):
    other = tmp_path / "other.h5"
    other.write_bytes(Path(single).read_bytes())
    p = _lmjx(["atlas", *TINY, "--seed", "5", "--out", str(other)])
    _, err = p.communicate(timeout=120)
    assert p.returncode == 2 and "other parameters" in err, err


def test_plain_reader_reads_the_atlas(single):
    import h5py

    with h5py.File(single, "r") as f:
        assert f.attrs["schema"] == "lmjx-atlas" and f["labels"].shape[0] == 21
        assert np.isfinite(f["area_npm_pm_m2"][...]).all()
        assert ReachConfig(cell=0.2).cell == f.attrs["cell_m"]
