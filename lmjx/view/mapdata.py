"""What the map view reads from a map file, and when: opening reads the header, the reach
map and the spatial index's offsets (a few hundred kB whatever the number of edges); the
edges over a cell are read when the cell is selected: its slice of the index, the per-edge
quantities the colours need, and the states of the edges drawn, nothing else.

`lmjx.mapfile.read.load_map` reads the whole index and every per-edge array at once
(hundreds of MB for a map of millions of edges); the viewer must open such a map in seconds,
so it reads the file itself.  A file this reader does not take for a valid map is handed to
`load_map`, whose one-line `MapFileError` says what is wrong with it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from lmjx.errors import MapFileError
from lmjx.mapfile.h5 import h5open
from lmjx.mapfile.lazystates import StateReader
from lmjx.mapfile.read import load_map, robot_for_file
from lmjx.mapfile.schema import SCHEMA, SCHEMA_VERSION, attr_str
from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.view.options import QUANTITIES


@dataclass
class CellEdges:
    """The edges over one reach cell (iy, ix), as far as they are drawn: `ids` all of them
    (ascending), `drawn` the ones read (an evenly spaced subset of at most the cap), with
    their quantity values and their states."""

    iy: int
    ix: int
    ids: np.ndarray  # (K,) int32 every edge over the cell
    drawn: np.ndarray  # (k,) int32 the edges drawn
    values: np.ndarray  # (k,) float32 the colour quantity of each drawn edge
    quantity: str
    p: list[np.ndarray] = field(default_factory=list)  # per drawn edge: (length, 3) interaction point [m]
    q: list[np.ndarray] = field(default_factory=list)  # per drawn edge: (length, nq) joint angles (swept arm)
    site: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int16))  # (k,) site index of each


class MapData:
    """A map file opened for viewing (see the module docstring).  Close it, or use `with`."""

    def __init__(self, path: str | Path, robot: Robot | None = None) -> None:
        p = Path(path)
        f = self._open(p)
        try:
            attrs = {k: f.attrs[k] for k in f.attrs}
            ok = attr_str(attrs.get("schema", "")) == SCHEMA and int(attrs.get("schema_version", -1)) == SCHEMA_VERSION
            if ok:
                robot = robot_for_file(p, attrs, robot)
                ok = attr_str(attrs.get("robot_model_hash", "")) == robot.model_hash and "reach" in f
        except Exception:
            f.close()
            raise
        if not ok:  # load_map says in one line what is wrong (or, for a map without a reach map, this does)
            f.close()
            with load_map(p, robot, lazy=True):
                pass
            raise MapFileError(f"{p} holds no reach map; the viewer shows maps from lmjx build-map or lmjx reach")
        assert robot is not None
        self.path = p
        self.file = f
        self.robot = robot
        self.attrs = attrs
        locked = tuple((int(j), float(a)) for j, a in zip(attrs["locked_joints"], attrs["locked_angles"], strict=True))
        self.failure = Failure(attr_str(attrs["failure"]), locked, robot.nq)
        try:
            r = f["reach"]
            self.cell = float(r.attrs["cell"])
            self.xs = r["x"][...]
            self.ys = r["y"][...]
            self.labels = r["labels"][...]
            self.labels_smooth = r["labels_smooth"][...]
            self.has_edges = "edges" in f
            self.index_offset = f["edges/index/offset"][...] if self.has_edges else np.zeros(1, np.int64)
        except (KeyError, OSError, ValueError) as e:
            f.close()
            raise MapFileError(f"{p} is damaged or incomplete ({type(e).__name__}: {e}); rebuild the map") from None
        if self.has_edges and len(self.index_offset) != len(self.xs) * len(self.ys) + 1:
            f.close()
            raise MapFileError(f"{p}: the spatial index does not match the reach map; rebuild the map")
        self._columns: dict[str, np.ndarray] = {}
        self._states: dict[str, StateReader] = {}

    @staticmethod
    def _open(p: Path) -> h5py.File:
        if not p.exists() or p.is_dir() or not h5py.is_hdf5(str(p)):
            with load_map(p, lazy=True):  # raises its one-line error
                pass
        try:
            return h5open(p, "r")
        except OSError as e:
            raise MapFileError(f"{p} is damaged or incomplete ({type(e).__name__}: {e}); rebuild the map") from None

    def __enter__(self) -> MapData:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        for reader in self._states.values():
            reader.close()
        self._states.clear()
        self.file.close()

    @property
    def nx(self) -> int:
        return len(self.xs)

    @property
    def ny(self) -> int:
        return len(self.ys)

    @property
    def n_edges(self) -> int:
        return int(self.file["edges/offset"].shape[0]) if self.has_edges else 0

    def edge_count(self) -> np.ndarray:
        """(ny, nx) how many edges act over each cell."""
        return np.diff(self.index_offset).reshape(self.ny, self.nx) if self.has_edges else np.zeros_like(self.labels)

    def busiest_cell(self) -> tuple[int, int] | None:
        """(iy, ix) of the cell the most edges act over (None without edges)."""
        counts = self.edge_count()
        if not counts.size or counts.max() == 0:
            return None
        iy, ix = np.unravel_index(int(np.argmax(counts)), counts.shape)
        return int(iy), int(ix)

    def cell_at(self, x: float, y: float) -> tuple[int, int] | None:
        """The cell (iy, ix) whose square holds the point (x, y), or None off the grid."""
        ix = int(np.floor((x - self.xs[0]) / self.cell + 0.5))
        iy = int(np.floor((y - self.ys[0]) / self.cell + 0.5))
        return (iy, ix) if 0 <= ix < self.nx and 0 <= iy < self.ny else None

    def column(self, name: str) -> np.ndarray:
        """A per-edge array, read whole on first use (E values: a few MB for a million edges)."""
        if name not in self._columns:
            self._columns[name] = self.file["edges"][name][...]
        return self._columns[name]

    def _reader(self, name: str) -> StateReader:
        if name not in self._states:
            self._states[name] = StateReader(self.file["edges"][name])
        return self._states[name]

    def edges_over(self, iy: int, ix: int) -> np.ndarray:
        """Ids of the edges whose arm acts over cell (iy, ix) (its slice of the index alone)."""
        if not self.has_edges:
            return np.zeros(0, np.int32)
        c = iy * self.nx + ix
        a, b = int(self.index_offset[c]), int(self.index_offset[c + 1])
        return self.file["edges/index/edges"][a:b] if b > a else np.zeros(0, np.int32)

    def cell_edges(self, iy: int, ix: int, cap: int, quantity: str, arm: bool = False) -> CellEdges:
        """The edges over (iy, ix): all their ids, and at most `cap` of them (evenly spaced over
        the ids) read with their `quantity` (a key of QUANTITIES) and states (`p`; `q` too for
        the swept arm)."""
        ids = self.edges_over(iy, ix)
        pick = np.unique(np.linspace(0, len(ids) - 1, cap).round().astype(np.int64))
        drawn = ids[pick] if len(ids) > cap else ids
        out = CellEdges(iy, ix, ids, drawn, np.zeros(len(drawn), np.float32), quantity)
        if not len(drawn):
            return out
        offset, length = self.column("offset")[drawn], self.column("length")[drawn]
        out.values = self.column(QUANTITIES[quantity][0])[drawn].astype(np.float32)
        out.site = self.column("site")[drawn]
        names = ("p", "q") if arm else ("p",)
        ranges = list(zip(offset.tolist(), (offset + length).tolist(), strict=True))
        for name in names:
            reader = self._reader(name)
            reader.prefetch(ranges)
            getattr(out, name).extend(np.asarray(reader[a:b]) for a, b in ranges)
        return out
