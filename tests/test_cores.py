"""lmjx.cores: the cores a run may use."""

from __future__ import annotations

import os

import pytest

from lmjx.cores import usable_cores
from lmjx.errors import ConfigError


def test_usable_cores_follow_the_affinity():
    """A run pinned to some cores (taskset) sizes its pools to them, not to the host."""
    mine = os.sched_getaffinity(0)
    try:
        os.sched_setaffinity(0, {min(mine)})
        assert usable_cores() == 1
    finally:
        os.sched_setaffinity(0, mine)
    assert usable_cores() == len(mine)


def test_lmjx_cores_caps_the_pools_without_pinning(monkeypatch):
    """LMJX_CORES=N: pools of at most N threads, affinity untouched; a bad value is refused."""
    mine = len(os.sched_getaffinity(0))
    monkeypatch.setenv("LMJX_CORES", "1")
    assert usable_cores() == 1
    assert len(os.sched_getaffinity(0)) == mine
    monkeypatch.setenv("LMJX_CORES", str(mine + 5))
    assert usable_cores() == mine
    monkeypatch.setenv("LMJX_CORES", "")
    assert usable_cores() == mine
    for bad in ("0", "two", "-1"):
        monkeypatch.setenv("LMJX_CORES", bad)
        with pytest.raises(ConfigError, match="LMJX_CORES"):
            usable_cores()


def test_lmjx_cores_1_keeps_xla_to_one_thread(monkeypatch):
    """LMJX_CORES=1 adds XLA's one-thread flags once (its CPU client would otherwise size its
    pool by the affinity); not with more cores or without LMJX_CORES; JAX starts with them."""
    import subprocess
    import sys

    from lmjx.cores import ONE_THREAD_XLA, cap_xla_threads

    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/nonexistent")
    monkeypatch.delenv("LMJX_CORES", raising=False)
    assert not cap_xla_threads() and os.environ["XLA_FLAGS"] == "--xla_dump_to=/nonexistent"
    if len(os.sched_getaffinity(0)) > 1:
        monkeypatch.setenv("LMJX_CORES", "2")
        assert not cap_xla_threads() and ONE_THREAD_XLA not in os.environ["XLA_FLAGS"]
    monkeypatch.setenv("LMJX_CORES", "1")
    assert cap_xla_threads()
    assert os.environ["XLA_FLAGS"] == f"--xla_dump_to=/nonexistent {ONE_THREAD_XLA}"
    assert not cap_xla_threads() and os.environ["XLA_FLAGS"].count(ONE_THREAD_XLA) == 1
    # XLA refuses a flag it does not know: the flags must still start a CPU backend
    code = "import jax, jax.numpy as jnp; print(float(jnp.ones((64, 64)).sum()))"
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "XLA_FLAGS": ONE_THREAD_XLA}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "4096.0", out.stderr[-2000:]
