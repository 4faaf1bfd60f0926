"""`lmjx info --verify`: a whole map file read and checked, one line per problem found.

Every chunk of every dataset is read: its Fletcher-32 checksum checked where the dataset
has one (every numeric dataset of a map lmjx writes; `mapfile.checksum`) and its deflate
stream decoded (that it decodes to a whole chunk), chunks read straight from the file and
checked on all cores; datasets stored another way are read through HDF5 (which checks
what it can).  Every attribute is read.  Then the arrays are checked against each other
and against the attributes: the edges' offsets and lengths against the stored states, the
spatial index's offsets and edge ids, the reach map's shapes and areas, the push counts'
shapes, the stored MJCF against the robot's model hash.  Nothing is written, and nothing
here needs the robot's model: a map of any robot is verified from its own contents.
"""

from __future__ import annotations

import hashlib
import math
import os
import zlib
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from lmjx.errors import MapFileError
from lmjx.mapfile.checksum import ChecksumError, strip_checksum
from lmjx.mapfile.h5 import h5open
from lmjx.mapfile.schema import PER_EDGE, READ_VERSIONS, SCHEMA, attr_str
from lmjx.runtime.cores import usable_cores

ROWS = 1 << 22  # values of a large array checked at a time
WINDOW = 64  # chunks read ahead of the checking threads
FILTERS = {h5py.h5z.FILTER_SHUFFLE, h5py.h5z.FILTER_DEFLATE, h5py.h5z.FILTER_FLETCHER32}


@dataclass
class Verification:
    """What `verify_map` found: `problems` (one line each; none: the file is whole) and what
    was read."""

    path: Path
    problems: list[str] = field(default_factory=list)
    datasets: int = 0
    chunks: int = 0  # chunks read and checked
    stored_bytes: int = 0  # bytes of chunks read
    checksummed: int = 0  # datasets with HDF5's Fletcher-32 checksum
    unchecked: list[str] = field(default_factory=list)  # chunked datasets without one (a map of an earlier lmjx)

    def summary(self) -> dict:
        return {"problems": self.problems, "datasets": self.datasets, "chunks": self.chunks,
                "stored_bytes": self.stored_bytes, "checksummed": self.checksummed,
                "without_checksum": self.unchecked}  # fmt: skip


def verify_map(path: str | Path, threads: int | None = None) -> Verification:
    """Read and check the whole map file at `path`.  MapFileError (one line) only when it is
    not an lmjx map at all (missing, not HDF5, another schema); damage is reported in
    `problems`."""
    p = Path(path)
    if not p.is_file():
        raise MapFileError(f"map file {p} does not exist" if not p.exists() else f"{p} is not a file")
    try:
        f = h5open(p, "r")
    except OSError as e:
        if not h5py.is_hdf5(str(p)):
            raise MapFileError(f"{p} is not an HDF5 file (an lmjx map is HDF5)") from None
        return Verification(p, [f"the file cannot be opened as HDF5 ({_line(e)})"])
    v = Verification(p)
    with f:
        try:
            if attr_str(f.attrs.get("schema", "")) != SCHEMA:
                raise MapFileError(f"{p} is an HDF5 file but not an lmjx map (no schema='{SCHEMA}' attribute)")
        except OSError as e:
            return Verification(p, [f"the root attributes cannot be read ({_line(e)})"])
        objects = _objects(f, v)
        with ThreadPoolExecutor(threads or usable_cores(), thread_name_prefix="lmjx-verify") as pool:
            for name, obj in objects:
                _attributes(name, obj, v)
                if isinstance(obj, h5py.Dataset):
                    _dataset(f, name, obj, v, pool)
        damaged = {line.split(":")[0] for line in v.problems}
        _consistency(f, v, damaged)
    return v


def _line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


def _objects(f: h5py.File, v: Verification) -> list[tuple[str, h5py.HLObject]]:
    """Every group and dataset, the root first; a part of the file's structure that cannot be
    walked is a problem."""
    out: list[tuple[str, h5py.HLObject]] = [("/", f)]

    def visit(name: str, obj: h5py.HLObject) -> None:
        out.append((name, obj))

    try:
        f.visititems(visit)
    except (OSError, KeyError, RuntimeError) as e:
        v.problems.append(f"the file's structure is damaged after {out[-1][0]} ({_line(e)})")
    return out


def _attributes(name: str, obj: h5py.HLObject, v: Verification) -> None:
    try:
        for key in obj.attrs:
            obj.attrs[key]
    except (OSError, KeyError, ValueError, TypeError) as e:
        v.problems.append(f"{name}: its attributes cannot be read ({_line(e)})")


def _dataset(f: h5py.File, name: str, ds: h5py.Dataset, v: Verification, pool: ThreadPoolExecutor) -> None:
    v.datasets += 1
    try:
        plist = ds.id.get_create_plist()
        filters = [plist.get_filter(i)[0] for i in range(plist.get_nfilters())]
    except OSError as e:
        v.problems.append(f"{name}: its storage cannot be read ({_line(e)})")
        return
    if ds.chunks is None or not set(filters) <= FILTERS or ds.dtype.kind == "O":
        _read_through_hdf5(name, ds, v)
        return
    checked = h5py.h5z.FILTER_FLETCHER32 in filters
    v.checksummed += checked
    if not checked:
        v.unchecked.append(name)
    size = int(np.prod(ds.chunks)) * ds.dtype.itemsize
    pipeline = list(filters)
    fd = os.open(f.filename, os.O_RDONLY)
    try:
        pending: list = []
        for offset, mask, address, nbytes in _chunks(name, ds, v):
            raw = os.pread(fd, nbytes, address + f.userblock_size)
            v.chunks += 1
            v.stored_bytes += nbytes
            pending.append(pool.submit(_check_chunk, raw, mask, pipeline, size, offset))
            if len(pending) >= WINDOW:
                _collect(name, pending, v)
        _collect(name, pending, v)
    finally:
        os.close(fd)


def _chunks(name: str, ds: h5py.Dataset, v: Verification) -> Iterator[tuple[tuple, int, int, int]]:
    """(offset, filter mask, address, size) of every chunk of `ds`; a chunk missing or an
    index that cannot be walked is a problem."""
    found: list[tuple[tuple, int, int, int]] = []
    try:
        ds.id.chunk_iter(lambda info: found.append((info.chunk_offset, info.filter_mask, info.byte_offset, info.size)))
    except (OSError, RuntimeError) as e:
        v.problems.append(f"{name}: its chunk index is damaged ({_line(e)})")
        return iter(())
    expected = math.prod(-(-n // c) for n, c in zip(ds.shape, ds.chunks, strict=True)) if ds.size else 0
    if len(found) != expected:
        v.problems.append(f"{name}: {expected - len(found)} of its {expected} chunks are missing")
    return iter(found)


def _check_chunk(raw: bytes, mask: int, pipeline: list[int], size: int, offset: tuple) -> str | None:
    """What is wrong with one stored chunk (None: nothing): its filters undone from the last
    (Fletcher-32) to the first, as HDF5 would, but for shuffle (which cannot fail)."""
    data: bytes | memoryview = raw
    where = f"the chunk at {tuple(int(x) for x in offset)}"
    try:
        for i in reversed(range(len(pipeline))):
            if mask & (1 << i):
                continue  # this filter was not applied to this chunk
            if pipeline[i] == h5py.h5z.FILTER_FLETCHER32:
                data = strip_checksum(bytes(data), where)
            elif pipeline[i] == h5py.h5z.FILTER_DEFLATE:
                data = zlib.decompress(data)
    except ChecksumError as e:
        return str(e)
    except zlib.error as e:
        return f"{where} does not decompress ({e})"
    if len(data) != size:
        return f"{where} holds {len(data)} bytes, not {size}"
    return None


def _collect(name: str, pending: list, v: Verification) -> None:
    for job in pending:
        problem = job.result()
        if problem is not None:
            v.problems.append(f"{name}: {problem}")
    pending.clear()


def _read_through_hdf5(name: str, ds: h5py.Dataset, v: Verification) -> None:
    """A dataset stored otherwise (contiguous, text, other filters): read whole by HDF5, a
    block of rows at a time."""
    try:
        if not ds.shape or ds.shape[0] == 0:
            ds[()]
            return
        rows = max(1, ROWS // max(1, ds.size // ds.shape[0]))
        for a in range(0, ds.shape[0], rows):
            ds[a : a + rows]
    except (OSError, ValueError, TypeError) as e:
        v.problems.append(f"{name}: cannot be read ({_line(e)})")


# ------------------------------------------------------------------------------ consistency


def _consistency(f: h5py.File, v: Verification, damaged: set[str]) -> None:
    """The arrays against each other and the attributes (each check skipped where a dataset
    it reads is damaged: that is reported already)."""

    def check(needs: tuple[str, ...], test: Callable[[], str | None]) -> None:
        if any(n in damaged or n not in f for n in needs):
            return
        try:
            problem = test()
        except (OSError, KeyError, ValueError, TypeError, IndexError) as e:
            problem = f"{', '.join(needs)}: cannot be checked ({_line(e)})"
        if problem:
            v.problems.append(problem)

    a = f.attrs
    version = int(a.get("schema_version", -1))
    if version not in READ_VERSIONS:
        known = ", ".join(map(str, READ_VERSIONS))
        v.problems.append(f"/: schema version {version} is not one this lmjx reads ({known})")
    check(("robot/mjcf",), lambda: _mjcf(f))
    check(("robot/joint_names", "robot/lower"), lambda: _joints(f))
    check(("reach/x", "reach/y", "reach/labels", "reach/labels_smooth", "reach/q"), lambda: _reach(f))
    contents = attr_str(a.get("contents", ""))
    if ("edges" in f) != (contents == "reach+edges"):
        v.problems.append(f"/: contents says '{contents}' but the file {'has' if 'edges' in f else 'has no'} /edges")
    if "edges" in f:
        per_edge = tuple(f"edges/{k}" for k in ("offset", *PER_EDGE))
        check((*per_edge, "edges/q", "edges/qd", "edges/p"), lambda: _edges(f))
        check(("edges/index/offset", "edges/index/edges", "edges/offset", "reach/x", "reach/y"), lambda: _index(f))
        if "edges/push" in f:
            check(("edges/push/counts", "edges/push/key", "reach/x", "reach/y"), lambda: _push(f))


def _mjcf(f: h5py.File) -> str | None:
    text = f["robot/mjcf"][()]
    text = text.decode() if isinstance(text, bytes) else str(text)
    want = attr_str(f.attrs.get("robot_model_hash", ""))
    # the hash is of the MJCF file's bytes, which may end its lines in CR LF
    if want not in {hashlib.sha256(t.encode()).hexdigest() for t in (text, text.replace("\n", "\r\n"))}:
        return "robot/mjcf: the stored model does not match the root's robot_model_hash"
    return None


def _joints(f: h5py.File) -> str | None:
    nq = len(f["robot/joint_names"])
    locked = np.asarray(f.attrs["locked_joints"])
    if len(f["robot/lower"]) != nq or len(locked) != len(np.asarray(f.attrs["locked_angles"])):
        return "/robot: the joint arrays or the root's locked joints and angles differ in length"
    if len(locked) and not (locked.min() >= 1 and locked.max() <= nq):
        return f"/: locked_joints {locked.tolist()} name joints the robot (J1..J{nq}) lacks"
    return None


def _reach(f: h5py.File) -> str | None:
    g = f["reach"]
    ny, nx = len(g["y"]), len(g["x"])
    nq = len(f["robot/joint_names"]) if "robot/joint_names" in f else g["q"].shape[-1]
    shapes = {"labels": (ny, nx), "labels_smooth": (ny, nx), "q": (ny, nx, nq), "attempt": (ny, nx),
              "site": (ny, nx), "target": (ny, nx, 4), "pos_err": (ny, nx)}  # fmt: skip
    for k, shape in shapes.items():
        if k in g and g[k].shape != shape:
            return f"reach/{k}: shape {g[k].shape}, not {shape} (the grid of x and y)"
    labels = g["labels_smooth"][...]
    if not np.isin(g["labels"][...], (0, 1, 2)).all() or not np.isin(labels, (0, 1, 2)).all():
        return "reach/labels: a label other than 0, 1, 2"
    cell = float(g.attrs["cell"])
    for level, attr in ((2, "area_pm_m2"), (1, "area_npm_pm_m2")):
        area = np.sum(labels >= level) * cell**2
        if attr in g.attrs and not math.isclose(area, float(g.attrs[attr]), rel_tol=1e-9, abs_tol=1e-12):
            return f"/reach: {attr} {float(g.attrs[attr]):g} does not match labels_smooth ({area:g} m^2)"
    return None


def _edges(f: h5py.File) -> str | None:
    g = f["edges"]
    n = len(g["offset"])
    for k in PER_EDGE:
        if len(g[k]) != n:
            return f"edges/{k}: {len(g[k])} rows, not one per edge ({n})"
    if "edges_valid" in g.attrs and int(g.attrs["edges_valid"]) != n:
        return f"/edges: edges_valid says {int(g.attrs['edges_valid'])}, the arrays hold {n} edges"
    states = len(g["q"])
    if len(g["qd"]) != states or len(g["p"]) != states:
        return f"edges/q, qd, p: {states}, {len(g['qd'])} and {len(g['p'])} rows, not equal"
    length = g["length"][...].astype(np.int64)
    offset = g["offset"][...].astype(np.int64)
    if n and (length.min() < 1 or offset[0] != 0 or (offset[1:] != offset[:-1] + length[:-1]).any()):
        return "edges/offset, edges/length: an edge's rows do not follow the one before"
    if n and offset[-1] + length[-1] != states:
        return f"edges/offset, edges/length: the edges end at row {offset[-1] + length[-1]}, the states at {states}"
    dt = float(g.attrs["dt"])
    if n and not np.allclose(g["duration"][...], (length - 1) * dt, rtol=1e-5, atol=1e-6):
        return "edges/duration: does not equal (length - 1) * dt"
    sites = len(f["robot/site_names"]) if "robot/site_names" in f else None
    site = g["site"][...]
    if n and sites is not None and (site.min() < 0 or site.max() >= sites):
        return f"edges/site: an index outside /robot/site_names (0..{sites - 1})"
    if "reach/x" in f and n:
        cell = g["start_cell"][...]
        if cell.min() < 0 or cell[:, 0].max() >= len(f["reach/y"]) or cell[:, 1].max() >= len(f["reach/x"]):
            return "edges/start_cell: a cell outside the reach map's grid"
    return None


def _index(f: h5py.File) -> str | None:
    g = f["edges/index"]
    ny, nx = len(f["reach/y"]), len(f["reach/x"])
    if int(g.attrs.get("nx", nx)) != nx or int(g.attrs.get("ny", ny)) != ny:
        return f"/edges/index: nx, ny {int(g.attrs['nx'])}, {int(g.attrs['ny'])}, not the reach map's {nx}, {ny}"
    offset = g["offset"][...].astype(np.int64)
    if len(offset) != ny * nx + 1 or offset[0] != 0 or (np.diff(offset) < 0).any():
        return "edges/index/offset: not ny * nx + 1 non-decreasing offsets from 0"
    ds = g["edges"]
    if offset[-1] != len(ds):
        return f"edges/index/offset: ends at {offset[-1]}, edges/index/edges holds {len(ds)}"
    n = len(f["edges/offset"])
    starts = offset[1:-1]  # a new cell's first entry
    for a in range(0, len(ds), ROWS):
        block = ds[a : a + ROWS].astype(np.int64)
        if len(block) and (block.min() < 0 or block.max() >= n):
            return f"edges/index/edges: an edge id outside 0..{n - 1}"
        within = np.ones(len(block) - 1, bool)  # pairs of the same cell: in edge order
        inner = starts[(starts > a) & (starts < a + len(block))] - a
        within[inner - 1] = False
        if (np.diff(block)[within] < 0).any():
            return "edges/index/edges: a cell's edges out of order"
    return None


def _push(f: h5py.File) -> str | None:
    g = f["edges/push"]
    k = len(g["key"])
    shape = (k, len(f["reach/y"]), len(f["reach/x"]))
    if g["counts"].shape != shape:
        return f"edges/push/counts: shape {g['counts'].shape}, not {shape}"
    for name in ("scenario", "tasks"):
        if name in g and len(g[name]) != k:
            return f"edges/push/{name}: {len(g[name])} entries, not {k}"
    return None
