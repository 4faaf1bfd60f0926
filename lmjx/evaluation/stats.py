"""Uncertainty of a success rate: the Wilson score interval, for the reports and the docs.

A cell of the evaluation is n trials with k successes; its rate k / n alone hides how little
15 trials pin it down.  The Wilson interval (the set of rates p for which the score test of
p does not reject k of n at the 5 % level) stays inside [0, 1] and keeps its coverage near 95 %
at 0 or n successes, where the normal approximation's collapses to a point.
"""

from __future__ import annotations

import math

Z95 = 1.959963984540054  # the standard normal's 97.5 % quantile: two-sided 95 %


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval (low, high) of a rate of k successes in n trials."""
    if n < 1 or not 0 <= k <= n:
        raise ValueError(f"wilson needs 0 <= k <= n and n >= 1, got k={k}, n={n}")
    p = k / n
    z2 = z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z / (1 + z2 / n) * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def _pct(x: float) -> str:
    return f"{100 * x:.1f}".removesuffix(".0")


def rate_text(k: int, n: int) -> str:
    """A cell's success as the reports write it: 'k/n (p %, 95 % CI lo-hi %)'."""
    lo, hi = wilson(k, n)
    return f"{k}/{n} ({_pct(k / n)} %, 95 % CI {_pct(lo)}-{_pct(hi)} %)"


def interval_text(k: int, n: int) -> str:
    """The interval alone, as the docs' tables add it to a rate: '[lo-hi]' in percent."""
    lo, hi = wilson(k, n)
    return f"[{_pct(lo)}-{_pct(hi)}]"
