"""lmjx.cores: the cores a run may use."""

from __future__ import annotations

import os

from lmjx.cores import usable_cores


def test_usable_cores_follow_the_affinity():
    """A run pinned to some cores (taskset) sizes its pools to them, not to the host."""
    mine = os.sched_getaffinity(0)
    try:
        os.sched_setaffinity(0, {min(mine)})
        assert usable_cores() == 1
    finally:
        os.sched_setaffinity(0, mine)
    assert usable_cores() == len(mine)
