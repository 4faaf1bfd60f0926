"""A streamed build's chunk files (lmjx.edges.chunkfile): a saved chunk reads back bit for bit,
whole or in part; a file a machine crash truncated is dropped from the saved ones, and one
whose bytes changed is removed with an error that says to rerun."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lmjx.edges import chunkfile
from lmjx.edges.chunk import EdgeChunk


def _chunk(seed: int, edges: int = 37) -> EdgeChunk:
    rng = np.random.default_rng(seed)
    length = rng.integers(2, 60, edges).astype(np.int32)
    s = int(length.sum())
    return EdgeChunk(
        start=1000, stop=2000, length=length,
        q=rng.normal(size=(s, 7)).astype(np.float32), qd=rng.normal(size=(s, 7)).astype(np.float32),
        p=rng.normal(size=(s, 3)).astype(np.float32), twist=rng.normal(size=(edges, 6)).astype(np.float32),
        duration=rng.random(edges).astype(np.float32), site=rng.integers(0, 9, edges).astype(np.int16),
        start_cell=rng.integers(0, 50, (edges, 2)).astype(np.int32),
        min_manipulability=rng.random(edges).astype(np.float32), peak_torque_ratio=rng.random(edges).astype(np.float32),
        peak_velocity_ratio=rng.random(edges).astype(np.float32),
        peak_acceleration_ratio=rng.random(edges).astype(np.float32),
        index_cell=np.sort(rng.integers(0, 900, 3 * edges)).astype(np.int32),
        index_edge=rng.integers(0, edges, 3 * edges).astype(np.int32),
        rejected=rng.integers(0, 100, 7).astype(np.int64), rolled_out=812, states_evaluated=12345,
        seconds={"ik": 0.5},
    )  # fmt: skip


def test_a_saved_chunk_reads_back_whole_and_in_part(tmp_path):
    c = _chunk(0)
    path = chunkfile.save(tmp_path, c)
    assert path.name == "edges-1000-2000.chunk" and chunkfile.saved_chunks(tmp_path) == [(1000, 2000)]
    back = chunkfile.load(tmp_path, 1000, 2000)
    for f in dataclasses.fields(EdgeChunk):
        x, y = getattr(c, f.name), getattr(back, f.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), f.name
            assert y.ctypes.data % 64 == 0 or y.nbytes == 0  # aligned views of one buffer
        else:
            assert x == y, f.name
    part, head = chunkfile.read(tmp_path, 1000, 2000, ("index_cell", "index_edge"))
    assert set(part) == {"index_cell", "index_edge"} and head["rolled_out"] == 812
    assert np.array_equal(part["index_edge"], c.index_edge)


def test_an_empty_chunk_round_trips(tmp_path):
    c = _chunk(1)
    empty = dataclasses.replace(c, length=c.length[:0], q=c.q[:0], qd=c.qd[:0], p=c.p[:0], twist=c.twist[:0],
                                index_cell=c.index_cell[:0], index_edge=c.index_edge[:0])  # fmt: skip
    chunkfile.save(tmp_path, empty)
    back = chunkfile.load(tmp_path, 1000, 2000)
    assert back.q.shape == (0, 7) and back.index_edge.shape == (0,) and np.array_equal(back.rejected, c.rejected)


def test_a_truncated_file_is_not_counted_as_saved(tmp_path):
    chunkfile.save(tmp_path, _chunk(2))
    c = dataclasses.replace(_chunk(3), start=2000, stop=3000)
    path = chunkfile.save(tmp_path, c)
    with open(path, "r+b") as fh:
        fh.truncate(path.stat().st_size - 10)
    (tmp_path / ".edges-5-6.chunk.123.tmp").write_bytes(b"x")  # an interrupted save
    assert chunkfile.saved_chunks(tmp_path) == [(1000, 2000)]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["edges-1000-2000.chunk"]


def test_a_changed_byte_is_caught_and_the_file_removed(tmp_path):
    c = _chunk(4)
    path = chunkfile.save(tmp_path, c)
    data = bytearray(path.read_bytes())
    data[-200] ^= 0x10  # somewhere in the last arrays
    path.write_bytes(bytes(data))
    assert chunkfile.saved_chunks(tmp_path) == [(1000, 2000)]  # the size is right
    with pytest.raises(chunkfile.ChunkFileError, match="rerun the same command"):
        chunkfile.load(tmp_path, 1000, 2000)
    assert not path.exists()
