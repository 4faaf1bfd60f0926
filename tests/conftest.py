"""Shared fixtures.  Tests run on the CPU (C MuJoCo is the reference everywhere)."""

from __future__ import annotations

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import mujoco
import numpy as np
import pytest

from lmjx.robot import load_robot


@pytest.fixture(scope="session")
def robot():
    return load_robot()


@pytest.fixture(scope="session")
def mj(robot):
    return robot.mj, mujoco.MjData(robot.mj)


def random_configs(robot, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return robot.lower + rng.random((n, robot.nq)) * (robot.upper - robot.lower)
