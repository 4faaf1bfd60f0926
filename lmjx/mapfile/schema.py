"""The map file's schema: its name and version, what each dataset holds, how configs are
stored as attributes.  Documented for readers that do not import lmjx (plain h5py, MATLAB,
C++) in maps/README.md; a later version adds groups and datasets without changing the
existing ones, so every version stays readable.
"""

from __future__ import annotations

import dataclasses
import math

import h5py
import numpy as np

SCHEMA = "lmjx-map"
SCHEMA_VERSION = 3  # 3: /edges/push, the push counts of the robot's built-in scenarios
# 2: the spatial index lists the edges whose whole arm (swept capsules) reaches a cell
READ_VERSIONS = (2, 3)  # what this lmjx reads (a version 2 map: its push counts computed when needed)
LABEL_MEANING = "0 unreachable, 1 NPM only (push/poke), 2 PM (grasp)"
STR_DTYPE = h5py.string_dtype(encoding="utf-8")
PER_EDGE = {
    "length": "states per edge (control steps + 1)",
    "q_start": "joint angles J1..J7 of each edge's first state [rad] (= q[offset]: where its transit goes)",
    "twist": "commanded twist of the interaction point: vx, vy, vz [m/s], wx, wy, wz [rad/s]",
    "duration": "edge duration [s] = (length - 1) * dt",
    "site": "index into /robot/site_names of the edge's interaction point",
    "start_cell": "(iy, ix) of the reach cell the edge starts from",
    "min_manipulability": "smallest sqrt(det(J J^T)) along the edge",
    "peak_torque_ratio": "max |tau_i| / tau_max_i over free joints and states",
    "peak_velocity_ratio": "max |qd_i| / qd_max_i",
    "peak_acceleration_ratio": "max |qdd_i| / qdd_max_i",
}

PER_STATE = {
    "q": "joint angles J1..J7 at each state [rad] (locked joints at their angles)",
    "qd": "joint velocities J1..J7 at each state [rad/s] (J^+ of the twist)",
    "p": "world position of the edge's interaction point at each state [m]",
}

STATE_ROWS = 16384  # rows per HDF5 chunk of q, qd, p
EDGE_ROWS = 65536  # rows per HDF5 chunk of the per-edge arrays
DEFLATE_LEVEL = 1  # the level of every dataset lmjx writes in chunks (zlib's level 4 compressed


def attr_str(x: object) -> str:
    return x.decode() if isinstance(x, bytes) else str(x)


def file_robot(attrs: dict) -> str:
    """The robot a map or atlas file names: a shipped robot's name, or a user MJCF's model
    name (files from before robots were named: the Panda)."""
    return attr_str(attrs.get("robot", "panda"))


def config_to_attrs(g: h5py.Group, config: object) -> None:
    """Every field of a config dataclass as a group attribute (None as NaN)."""
    for f in dataclasses.fields(config):  # type: ignore[arg-type]
        v = getattr(config, f.name)
        if v is None:
            v = float("nan")
        if isinstance(v, tuple):
            v = np.array([str(x) for x in v], dtype=object) if v and isinstance(v[0], str) else np.array(v)
        g.attrs[f.name] = v


def config_from_attrs(cls: type, a: dict):
    """Rebuild a config dataclass from group attributes, casting each field like its default."""
    values = {}
    for f in dataclasses.fields(cls):
        if f.name not in a:
            continue
        v = a[f.name]
        default = f.default
        if isinstance(v, float) and math.isnan(v):
            values[f.name] = None
        elif isinstance(default, tuple):
            values[f.name] = tuple(attr_str(x) if isinstance(x, (str, bytes)) else float(x) for x in v)
        elif isinstance(default, bool):
            values[f.name] = bool(v)
        elif isinstance(default, int) or (default is None and float(v).is_integer()):
            values[f.name] = int(v)
        elif isinstance(default, str):
            values[f.name] = attr_str(v)
        else:
            values[f.name] = float(v)
    return cls(**values)
