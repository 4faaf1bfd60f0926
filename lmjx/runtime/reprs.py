"""Short `repr`s for the objects users print: one line each, never an array's contents.

A config prints the fields that differ from its defaults (`ReachConfig(cell=0.05)`); a
result prints its name and key figures.  Nothing here computes anything.
"""

from __future__ import annotations

import dataclasses
from typing import Any


def _short(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, tuple) and all(isinstance(v, float) for v in value):
        return "(" + ", ".join(f"{v:g}" for v in value) + ")"
    return repr(value)


def config_repr(obj: Any) -> str:
    """`Name(field=value, ...)` for the fields of a frozen config dataclass that differ from
    its defaults (a field without a default is always shown)."""
    parts = []
    for f in dataclasses.fields(obj):
        if not f.repr:
            continue
        value = getattr(obj, f.name)
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            parts.append(f"{f.name}={_short(value)}")
            continue
        if value != default:
            parts.append(f"{f.name}={_short(value)}")
    return f"{type(obj).__name__}({', '.join(parts)})"
