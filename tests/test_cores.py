"""lmjx.runtime.cores: the cores a run may use."""

from __future__ import annotations

import os

import pytest

from lmjx.errors import ConfigError
from lmjx.runtime.cores import usable_cores


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
