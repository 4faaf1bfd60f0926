"""Checks of the numbers users give: seeds, counts and finite numbers in range.

The commands' argument types (`lmjx.cli.common`) and the public functions (`lmjx.api`,
the configs' `validate`) use the same checks, so a seed of -1 or a count of 0 is refused in
one line (`ConfigError`) wherever it is given, before any work or any file.  Nothing here
computes anything else.
"""

from __future__ import annotations

import math
import numbers

from lmjx.errors import ConfigError

# Seeds are whole numbers 0 .. 2**32 - 1: JAX's random keys keep the low 32 bits of a larger
# seed (two seeds would then draw the same numbers), and every seed lmjx derives stays a
# seed `lmjx plan --seed` takes.
SEED_MAX = 2**32 - 1


def whole_number(value: object, name: str, least: int | None = None, most: int | None = None) -> int:
    """`value` as an int when it is a whole number (not a bool) in [least, most], else a
    one-line ConfigError naming `name`."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ConfigError(f"{name} must be a whole number, got {value!r}")
    v = int(value)
    if least is not None and v < least:
        raise ConfigError(f"{name} must be at least {least}, got {v}")
    if most is not None and v > most:
        raise ConfigError(f"{name} must be at most {most:,}, got {v:,}")
    return v


def seed(value: object, name: str = "seed") -> int:
    """A seed: a whole number from 0 to `SEED_MAX`."""
    return whole_number(value, name, 0, SEED_MAX)


def finite_number(value: object, name: str, above: float | None = None, least: float | None = None,
                  most: float | None = None) -> float:  # fmt: skip
    """`value` as a float when it is a finite number (not a bool) > `above`, >= `least` and
    <= `most` (those given), else a one-line ConfigError naming `name`."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(float(value)):
        raise ConfigError(f"{name} must be a finite number, got {value!r}")
    v = float(value)
    if above is not None and not v > above:
        raise ConfigError(f"{name} must be above {above:g}, got {v:g}")
    if least is not None and v < least:
        raise ConfigError(f"{name} must be at least {least:g}, got {v:g}")
    if most is not None and v > most:
        raise ConfigError(f"{name} must be at most {most:g}, got {v:g}")
    return v
