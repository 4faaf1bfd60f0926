"""The content digest a streamed build stores (`lmjx.edges.mapappend`): hashed from the bytes
the writing process has (the durations and the index as written, the states from the chunk
files) instead of decompressing the map, and always `content_digest`'s, whichever way it is
read: for maps of several chunks and index ranges, for a resumed build, and, through the
fallback, where the map is not what the fast way assumes (another schema, a chunk file
missing or of other rows, another definition of what is hashed)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import h5py
import numpy as np
import pytest
from conftest import TINY_MAP, cli

from lmjx.edges import chunkfile, mapappend
from lmjx.edges.chunk import EdgeChunk
from lmjx.mapfile.bundle import BundleConfig
from lmjx.mapfile.digest import content_digest, stored_digest
from lmjx.mapfile.write import IndexGrid, edges_group

NQ, GRID, REASONS = 4, IndexGrid(6, 5, 0.1), ("ik", "collision")
APPENDED = tuple(k for k in EdgeChunk.ARRAYS if k != "index_edge")
FINISH = {"seconds": 0.0, "compile_seconds": 0.0, "rollout_seconds": 0.0, "device": "cpu"}


def _chunk(rng: np.random.Generator, a: int, b: int, n_edges: int, rows: int | None = None) -> EdgeChunk:
    """Random packed edges of sampled edges [a, b): their states (`rows` of q, if given, else
    as their lengths add up) and unique index pairs sorted by (cell, edge)."""
    length = rng.integers(2, 9, n_edges).astype(np.int32)
    states = int(length.sum())

    def f32(*shape: int) -> np.ndarray:
        return rng.standard_normal(shape).astype(np.float32)

    cells = rng.integers(0, GRID.nx * GRID.ny, 3 * n_edges)
    pairs = np.unique(np.stack([cells, rng.integers(0, max(n_edges, 1), len(cells))], 1), axis=0)
    return EdgeChunk(
        start=a, stop=b, length=length, q=f32(states if rows is None else rows, NQ), qd=f32(states, NQ),
        p=f32(states, 3), twist=f32(n_edges, 6), duration=np.abs(f32(n_edges)),
        site=rng.integers(0, 5, n_edges).astype(np.int16), start_cell=rng.integers(0, 5, (n_edges, 2)).astype(np.int32),
        min_manipulability=f32(n_edges), peak_torque_ratio=f32(n_edges), peak_velocity_ratio=f32(n_edges),
        peak_acceleration_ratio=f32(n_edges), index_cell=pairs[:, 0].astype(np.int32),
        index_edge=pairs[:, 1].astype(np.int32), rejected=rng.integers(0, 9, len(REASONS)).astype(np.int64),
        rolled_out=n_edges, states_evaluated=states,
    )  # fmt: skip


class _Inbox:
    """The build's side of a resumed build: every chunk saved already, then "finish"."""

    def recv(self) -> tuple:
        return ("finish", FINISH)

    def poll(self, timeout: float = 0.0) -> bool:
        return False


def _written(
    tmp_path: Path, head_extra: str | None = None, edges: tuple[int, ...] = (40, 0, 25, 60)
) -> mapappend._Appender:
    """A map written by the writing process's code in this process from random chunk files (one
    without valid edges), its index in several ranges; `head_extra`: a dataset added to the
    map's head; `edges`: each chunk's valid edges."""
    folder = tmp_path / "partial"
    folder.mkdir()
    rng = np.random.default_rng(5)
    ranges = [(0, 100), (100, 200), (200, 300), (300, 400)]
    for (a, b), n_edges in zip(ranges, edges, strict=True):
        chunkfile.save(folder, _chunk(rng, a, b, n_edges))
    tmp = folder / "map.h5.tmp"
    with h5py.File(tmp, "w", track_order=True) as f:
        f.create_dataset("robot/lower", data=np.linspace(-1, 1, NQ))
        f.create_dataset("robot/joint_names", data=np.array([f"J{i}" for i in range(NQ)], dtype=object),
                         dtype=h5py.string_dtype())  # fmt: skip
        f.create_dataset("reach/labels", data=rng.integers(0, 3, (GRID.ny, GRID.nx)).astype(np.int8))
        edges_group(f, BundleConfig())
        if head_extra is not None:
            f.create_dataset(head_extra, data=np.arange(3))
    job = mapappend.Job(folder, NQ, 400, ranges, set(ranges), 2, tmp, GRID, 10, REASONS, APPENDED)
    appender = mapappend._Appender(job, _Inbox())
    appender.run()
    return appender


def _both_ways(path: Path) -> str:
    """The map's content digest, asserted the same read on all cores and through h5py."""
    digest = content_digest(path)[0]
    assert content_digest(path, parallel=False)[0] == digest
    return digest


def test_the_digest_from_the_chunk_files_is_the_maps(tmp_path, monkeypatch):
    monkeypatch.setattr(mapappend, "INDEX_PAIRS", 37)  # the index's ids written (and hashed) in several ranges
    appender = _written(tmp_path)
    digest, source = appender.digest()
    assert source == "chunk files" and digest == _both_ways(appender.job.tmp)
    with h5py.File(appender.job.tmp) as f:
        assert len(f["edges/index/edges"]) > 5 * 37 and f["edges/duration"].shape == (125,)


def test_a_map_without_valid_edges_is_written_with_its_digest(tmp_path):
    """No chunk with a valid edge: the map's index is empty (no HDF5 chunk to write), and its
    digest is still `content_digest`'s."""
    appender = _written(tmp_path, edges=(0, 0, 0, 0))
    digest, source = appender.digest()
    assert source == "chunk files" and digest == _both_ways(appender.job.tmp)
    with h5py.File(appender.job.tmp) as f:
        assert f["edges/index/edges"].shape == (0,) and f["edges/duration"].shape == (0,)
        assert not f["edges/index/offset"][()].any()


@pytest.mark.parametrize("broken", ["schema", "missing chunk", "other rows", "definition"])
def test_a_map_not_as_assumed_gets_the_digest_read_from_it(tmp_path, monkeypatch, broken):
    """Another dataset sorting first, a chunk file gone or holding other rows than appended,
    or another definition of what is hashed: the digest is read from the map instead."""
    appender = _written(tmp_path, "edges/count" if broken == "schema" else None)
    folder = appender.job.folder
    if broken == "missing chunk":
        chunkfile.chunk_path(folder, 200, 300).unlink()
    if broken == "other rows":  # q a row short: found after the p rows were hashed, before the map's q
        chunkfile.save(folder, _chunk(np.random.default_rng(5), 200, 300, 25, rows=3))
        assert len(chunkfile.read(folder, 200, 300, ("q",))[0]["q"]) == 3
    if broken == "definition":  # the durations no longer content
        monkeypatch.setattr("lmjx.mapfile.digest.DERIVED", ("edges/push", "edges/duration"))
    digest, source = appender.digest()
    assert source == "map" and digest == _both_ways(appender.job.tmp)


def test_a_build_and_its_resumption_store_the_digest_of_their_chunk_files(tmp_path, monkeypatch):
    """`lmjx build-map` of several chunks stores `content_digest` of its map, computed from
    the chunk files; the same command again, on the chunks the first one kept (its partial
    folder left in place here), resumes the build from them and stores the same digest."""
    import lmjx.edges.mapwriter

    monkeypatch.setattr(lmjx.edges.mapwriter, "shutil", SimpleNamespace(rmtree=lambda *args, **kwargs: None))
    out = tmp_path / "tiny.h5"
    args = ("build-map", *TINY_MAP, "--out", out, "--json")
    first = json.loads(cli(*args).ok().stdout)["edges"]
    assert first["digest_from"] == "chunk files" and first["writer_timing"]["digest"] > 0
    digest = stored_digest(out)
    assert digest == _both_ways(out)
    assert len(list(Path(f"{out}.partial").glob("edges-*.chunk"))) >= 3
    out.rename(tmp_path / "first.h5")
    second = cli(*args).ok()
    assert "resuming the build kept in" in second.stderr
    assert json.loads(second.stdout)["edges"]["digest_from"] == "chunk files"
    assert stored_digest(out) == digest == _both_ways(out)
