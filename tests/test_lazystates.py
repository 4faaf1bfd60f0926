"""The lazy state reader (lmjx/mapfile/lazystates.py) against h5py reading the same datasets."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from lmjx.mapfile.lazystates import StateReader
from lmjx.mapfile.schema import STATE_ROWS
from lmjx.mapfile.write import _write_chunks


@pytest.fixture(scope="module")
def states_file(tmp_path_factory):
    """Three datasets of the same rows: written as lmjx writes maps (raw chunks through its
    own shuffle + deflate), by h5py's filters with another chunk height, and with LZF."""
    rng = np.random.default_rng(0)
    n = 2 * STATE_ROWS + 5123  # the last chunk partly filled
    data = rng.normal(size=(n, 7)).astype(np.float32)
    path = tmp_path_factory.mktemp("lazy") / "states.h5"
    with h5py.File(path, "w") as f:
        ds = f.create_dataset("lmjx", shape=(n, 7), dtype=np.float32, chunks=(STATE_ROWS, 7),
                              compression="gzip", compression_opts=4, shuffle=True)  # fmt: skip
        # two pieces per chunk, as the writer gets them; the first two chunks in one job
        chunks = [(a, [data[a : a + 100], data[a + 100 : a + STATE_ROWS]]) for a in range(0, n, STATE_ROWS)]
        _write_chunks(ds, chunks[:2], STATE_ROWS, ds.dtype)
        _write_chunks(ds, chunks[2:], STATE_ROWS, ds.dtype)
        f.create_dataset("h5py", data=data, chunks=(1000, 7), compression="gzip", shuffle=True)
        f.create_dataset("lzf", data=data, chunks=(1000, 7), compression="lzf")
    return path, data


@pytest.mark.parametrize("name", ["lmjx", "h5py", "lzf"])
def test_rows_equal_h5py_and_the_written_data(states_file, name):
    path, data = states_file
    rng = np.random.default_rng(1)
    with h5py.File(path, "r") as f:
        ds = f[name]
        r = StateReader(ds, cache_bytes=2 * 2**20)  # small: evictions happen
        assert r.fast == (name != "lzf")
        assert len(r) == len(data) and r.shape == data.shape
        starts = rng.integers(0, len(data) - 1, 300)
        lens = rng.integers(1, 120, 300)
        ranges = [(int(a), int(min(a + k, len(data)))) for a, k in zip(starts, lens, strict=True)]
        ranges += [(0, 1), (STATE_ROWS - 3, STATE_ROWS + 3), (len(data) - 7, len(data))]  # chunk edges, the end
        r.prefetch(ranges[:100])
        for a, b in ranges:
            got = r[a:b]
            assert got.dtype == np.float32 and got.shape == (b - a, 7)
            np.testing.assert_array_equal(got, ds[a:b])
            np.testing.assert_array_equal(got, data[a:b])
        assert r.held <= r.cache_bytes or len(r.cache) == 1
        np.testing.assert_array_equal(r[5:5], np.zeros((0, 7), np.float32))
        np.testing.assert_array_equal(r[: len(data)], data)  # a long read goes through h5py
        r.close()


def test_a_read_whose_new_chunks_evict_its_cached_ones(states_file):
    """A slice over a cached chunk (the least recently used) and an uncached one: caching the
    new chunk evicts the old one, and the read still returns both (a 1,000,000-edge
    evaluation on the H100 stopped here with a KeyError)."""
    path, data = states_file
    with h5py.File(path, "r") as f:
        ds = f["h5py"]  # chunks of 1,000 rows, shuffle + deflate: the fast path
        chunk = 1000 * 7 * 4
        r = StateReader(ds, cache_bytes=4 * chunk, threads=1)
        assert r.fast and r.rows == 1000
        for a in (0, 5000, 6000, 7000):  # the cache full: chunks 0, 5, 6, 7
            np.testing.assert_array_equal(r[a : a + 1], data[a : a + 1])
        assert list(r.cache) == [0, 5, 6, 7] and r.held == r.cache_bytes
        np.testing.assert_array_equal(r[999:1001], data[999:1001])  # chunks 0 (cached) and 1 (new)
        assert r.held <= r.cache_bytes and 1 in r.cache
        r.close()
