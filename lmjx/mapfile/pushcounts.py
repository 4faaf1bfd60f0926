"""The push counts a map stores (`/edges/push`): those of its robot's built-in scenarios and
both task sets, computed when the map is built (`lmjx.mapfile.pushmap.builtin_counts`),
so that the planner's push weight costs nothing on the first decision.

The group holds one entry per scenario and task set: `key` (the planner's name for the
counts, `pushfield.counts_key`: a hash of what they are computed from, JAX's platform
included), `scenario`, `tasks` and `counts` (ny, nx) per reach cell.  The counts are derived
from the rest of the map: the map's content digest (`lmjx.mapfile.digest`) leaves them out.
"""

from __future__ import annotations

import h5py
import numpy as np

from lmjx.mapfile.schema import STR_DTYPE

GROUP = "push"  # in /edges


def write_push_counts(edges: h5py.Group, entries: list, attrs: dict) -> None:
    """/edges/push from `entries` (`pushfield.StoredCounts`), with `attrs` on the group
    (the settings they were computed with)."""
    g = edges.create_group(GROUP, track_order=True)
    g.attrs["doc"] = (
        "Push counts of the robot's built-in scenarios (entry i: scenario[i] of the task set tasks[i]): "
        "counts[i, iy, ix] = how many edges push a target over reach cell (iy, ix) toward the goal; "
        "key[i] names them for lmjx's planner (valid on the platform the attributes name)."
    )
    for name, value in attrs.items():
        g.attrs[name] = value
    counts = np.stack([e.counts for e in entries]).astype(np.int32)  # (the robot's built-in scenarios: some)
    for name, data, dtype, doc in (
        ("key", [e.key for e in entries], STR_DTYPE, "the planner's name of each entry's counts (a hash)"),
        ("scenario", [e.scenario for e in entries], np.int8, "scenario number (1, 2, 3)"),
        ("tasks", [e.tasks for e in entries], STR_DTYPE, "task set (paper, hard)"),
    ):
        checked = {} if dtype is STR_DTYPE else {"chunks": True, "fletcher32": True}  # (text takes no filter)
        ds = g.create_dataset(name, data=np.array(data, dtype=object if dtype is STR_DTYPE else dtype), dtype=dtype,
                              track_times=False, **checked)  # fmt: skip
        ds.attrs["doc"] = doc
    ds = g.create_dataset("counts", data=counts, compression="gzip", compression_opts=4, shuffle=True,
                          chunks=(1, *counts.shape[1:]), fletcher32=True, track_times=False)  # fmt: skip
    ds.attrs["doc"] = "(entries, ny, nx) edges pushing toward the goal over each reach cell"


def read_push_counts(edges: h5py.Group) -> dict[str, np.ndarray]:
    """key -> (ny, nx) counts of /edges/push (empty for a map without them)."""
    if GROUP not in edges:
        return {}
    g = edges[GROUP]
    keys = [k.decode() if isinstance(k, bytes) else str(k) for k in g["key"][...]]
    counts = g["counts"][...]
    return {k: counts[i] for i, k in enumerate(keys)}
