"""lmjx.runtime.batching.ChunkedKernel: padded chunks give every item's result, and the `kept`
outputs come back for the kept items only, in item order: compacted on the device, copying
only the blocks that hold them (the accelerators' way, asked for here on the CPU), or
selected on the host (a CPU's default); checked against plain numpy on the same items."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
import pytest

from lmjx.runtime.batching import KEEP_BLOCKS, ChunkedKernel


class _Out(NamedTuple):
    keep: jnp.ndarray
    score: jnp.ndarray
    traj: jnp.ndarray


def _one(x):
    return _Out(keep=x[0] > 0.5, score=x.sum(), traj=jnp.outer(x, jnp.arange(1.0, 4.0)))


def _reference(x: np.ndarray) -> dict[str, np.ndarray]:
    keep = x[:, 0] > 0.5
    traj = x[:, :, None] * np.arange(1.0, 4.0, dtype=np.float32)
    return {"keep": keep, "score": x.sum(axis=1), "traj": traj[keep]}


@pytest.mark.parametrize(("n", "chunk", "frac"), [(100, 37, 0.5), (64, 64, 0.05), (50, 20, 0.0), (30, 8, 1.0)])
def test_kept_rows_are_the_host_selection(n, chunk, frac):
    rng = np.random.default_rng(n)
    x = rng.random((n, 5)).astype(np.float32)
    x[:, 0] = np.where(rng.random(n) < frac, 0.9, 0.1)
    k = ChunkedKernel(("test-keep", chunk), _one, [], [(np.float32, (5,))], chunk, keep_by="keep", kept=("traj",),
                      compact=True)  # fmt: skip
    got = k.run(x)
    want = _reference(x)
    assert set(got) == set(want)
    np.testing.assert_array_equal(got["keep"], want["keep"])
    np.testing.assert_allclose(got["score"], want["score"], rtol=1e-6)
    np.testing.assert_array_equal(got["traj"], want["traj"])
    assert got["traj"].dtype == np.float32 and got["traj"].shape[1:] == (5, 3)
    # only the blocks holding kept rows were copied: at most one block more per launch than needed
    launches = -(-n // chunk)
    block_bytes = -(-chunk // KEEP_BLOCKS) * 5 * 3 * 4
    plain = launches * chunk * (1 + 4)  # keep (bool) and score (float32) come back whole
    assert k.copied_bytes <= plain + want["traj"].nbytes + launches * block_bytes
    # kept rows placed where `kept_dest` says (each copied once, straight to its row)
    dest = np.random.default_rng(1).permutation(int(want["keep"].sum()))
    seen = []
    placed = k.run(x, kept_dest=lambda keep: seen.append(keep.copy()) or dest)
    np.testing.assert_array_equal(seen[0], want["keep"])
    np.testing.assert_array_equal(placed["traj"][dest], want["traj"])
    np.testing.assert_array_equal(placed["keep"], want["keep"])
    # selected on the host (every row copied): the same results, placed the same way
    host = ChunkedKernel(("test-keep", chunk), _one, [], [(np.float32, (5,))], chunk, keep_by="keep", kept=("traj",),
                         compact=False)  # fmt: skip
    assert not host.compact
    for name, value in host.run(x).items():
        np.testing.assert_array_equal(value, got[name])
    np.testing.assert_array_equal(host.run(x, kept_dest=lambda keep: dest)["traj"][dest], want["traj"])


def test_without_keep_every_row_comes_back():
    x = np.random.default_rng(0).random((45, 5)).astype(np.float32)
    got = ChunkedKernel(("test-nokeep",), _one, [], [(np.float32, (5,))], 16).run(x)
    x_traj = x[:, :, None] * np.arange(1.0, 4.0, dtype=np.float32)
    np.testing.assert_array_equal(got["traj"], x_traj)
    assert len(got["keep"]) == 45


def test_empty_batch_has_the_result_shapes():
    k = ChunkedKernel(("test-empty",), _one, [], [(np.float32, (5,))], 16, keep_by="keep", kept=("traj",),
                      compact=True)  # fmt: skip
    got = k.run(np.zeros((0, 5), np.float32))
    assert got["traj"].shape == (0, 5, 3) and got["keep"].shape == (0,)


def test_kept_rows_from_several_devices():
    """The same on 3 host devices (a sharded kernel: each device compacts its own rows), and
    with the kernel bound to one of them."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    code = """
import sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from test_batching import _one, _reference
from lmjx.runtime.batching import ChunkedKernel
for n, chunk, frac in [(100, 7, 0.5), (500, 40, 0.3), (64, 64, 1.0), (50, 20, 0.0)]:
    rng = np.random.default_rng(n)
    x = rng.random((n, 5)).astype(np.float32)
    x[:, 0] = np.where(rng.random(n) < frac, 0.9, 0.1)
    k = ChunkedKernel(("t3", chunk), _one, [], [(np.float32, (5,))], chunk, sharded=True,
                      keep_by="keep", kept=("traj",), compact=True)
    assert k.mesh is not None and k.mesh.size == 3
    got, want = k.run(x), _reference(x)
    assert np.array_equal(got["traj"], want["traj"]) and np.array_equal(got["keep"], want["keep"]), (n, chunk)
    # the one-device program bound to the third device (a build's per-device kernels)
    import jax
    k = ChunkedKernel(("t3", chunk), _one, [], [(np.float32, (5,))], chunk, keep_by="keep", kept=("traj",),
                      device=jax.devices()[2], compact=True)
    assert k.mesh is None
    got = k.run(x)
    assert k._fn.input_shardings[0][0].device_set == {jax.devices()[2]}
    assert np.array_equal(got["traj"], want["traj"]) and np.array_equal(got["keep"], want["keep"]), (n, chunk)
print("ok")
"""
    env = dict(os.environ, JAX_PLATFORMS="cpu", XLA_FLAGS="--xla_force_host_platform_device_count=3")
    r = subprocess.run([sys.executable, "-c", code, str(Path(__file__).parent)], env=env, capture_output=True,
                       text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr[-2000:]
