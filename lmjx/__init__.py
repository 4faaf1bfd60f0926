"""lmjx: keep a robot arm with locked joints useful, with whole-body non-prehensile actions.

Public API (everything else is internal):
  load_robot(name_or_path)          a robot ('panda', the default; 'ur5e'; or an MJCF's path)
  robots(), check_robot(path)       the shipped robots; what an MJCF lacks (docs/ROBOTS.md)
  parse_failure(spec, robot)        'none', one of the robot's presets or 'J2=0.3,J4=-1.5'
  ReachConfig, reach_map(failure)   the Reach-Ability map (paper Algorithm 1)
  write_reach_map(path, result)     write a map file (schema: maps/README.md)
  load_map(path)                    read and validate a map file (its robot from the file)
  LmjxError                         base class of errors caused by user input

Names are imported on first use, so that `import lmjx` (and `lmjx --help`) stays light.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_EXPORTS = {
    "Failure": "failure",
    "parse_failure": "failure",
    "LmjxError": "errors",
    "ReachConfig": "reach",
    "ReachResult": "reach",
    "reach_map": "reach",
    "load_map": "mapfile",
    "write_reach_map": "mapfile",
    "Robot": "robot",
    "load_robot": "robot",
    "robots": "robot",
    "check_robot": "robot",
}

__all__ = ["__version__", *sorted(_EXPORTS)]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module 'lmjx' has no attribute '{name}'")
