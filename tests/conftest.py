"""Shared fixtures.  Tests run on the CPU (C MuJoCo is the reference everywhere)."""

from __future__ import annotations

import os
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# Compiled kernels are shared by the tests and the CLI processes they start (same machine,
# same code): a persistent compilation cache spares recompiling the same program.
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.join(tempfile.gettempdir(), f"lmjx-test-jax-{os.getuid()}"))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")
# On a GPU machine JAX and MuJoCo Warp share the GPU: JAX must not take most of it up front.
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

import numpy as np
import pytest


@pytest.fixture(scope="session")
def robot():
    from lmjx.robot import load_robot  # imported here: tests/test_plain_reader.py imports no lmjx

    return load_robot()


@pytest.fixture(scope="session", params=["panda", "ur5e"])
def arm(request):
    """Each shipped robot in turn, for the kernel tests that must hold for any arm."""
    from lmjx.robot import load_robot

    return load_robot(request.param)


def random_configs(robot, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return robot.lower + rng.random((n, robot.nq)) * (robot.upper - robot.lower)
