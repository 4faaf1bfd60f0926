"""Capsules that enclose a link's collision geometry: the fit `lmjx robot import` uses.

A link's collision geometry (mesh vertices, or points on a primitive's surface, in the link's
frame) is covered by one to `MAX_CAPSULES` capsules, every point inside one of them:

  * one capsule, for a candidate axis d (the points' three principal axes and the frame's
    three axes): the points projected on the plane normal to d get their smallest enclosing
    circle (centre c, radius r; Welzl's algorithm on their convex hull); the segment along d
    through c is then the shortest that covers every point, since a point at axial t and
    radial distance rho <= r is inside iff it lies within sqrt(r^2 - rho^2) of the segment
    (the segment is [min(t + s), max(t - s)] with s = sqrt(r^2 - rho^2)).  The axis of the
    smallest volume wins.
  * k capsules: the points split into k slabs across one of their principal axes (each
    tried), the cuts searched on a grid of quantiles; each slab gets its own capsule.  One more
    capsule is taken only if it cuts the summed volume by `GAIN` or more.

Every point is covered by construction (`coverage` measures it); the tightness is the union's
volume over the geometry's (`union_volume`, Monte Carlo with a fixed seed).  Pure numpy and
scipy; nothing here knows MuJoCo.
"""

from __future__ import annotations

import contextlib
import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.spatial import ConvexHull, QhullError

MAX_CAPSULES = 4
GAIN = 0.05  # another capsule must cut the summed volume by this share
MIN_HALF = 5e-4  # [m] half length of a capsule whose points need no length (a sphere's)


@dataclass(frozen=True)
class Capsule:
    a: np.ndarray  # (3,) segment end
    b: np.ndarray  # (3,) segment end
    r: float  # radius [m]

    @property
    def volume(self) -> float:
        return math.pi * self.r**2 * float(np.linalg.norm(self.b - self.a)) + 4.0 / 3.0 * math.pi * self.r**3


def segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n,) distances of points p (n, 3) to the segment a-b."""
    ab = b - a
    t = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def _circle2(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, float]:
    c = (p + q) / 2
    return c, float(np.linalg.norm(p - c))


def _circle3(p: np.ndarray, q: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, float]:
    ax, ay = p
    bx, by = q
    cx, cy = s
    d = 2 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
    if abs(d) < 1e-18:  # collinear: the widest pair's circle
        return max((_circle2(u, v) for u, v in ((p, q), (p, s), (q, s))), key=lambda t: t[1])
    ux = ((ax**2 + ay**2) * (by - cy) + (bx**2 + by**2) * (cy - ay) + (cx**2 + cy**2) * (ay - by)) / d
    uy = ((ax**2 + ay**2) * (cx - bx) + (bx**2 + by**2) * (ax - cx) + (cx**2 + cy**2) * (bx - ax)) / d
    c = np.array([ux, uy])
    return c, float(np.linalg.norm(p - c))


def enclosing_circle(points: np.ndarray, seed: int = 0) -> tuple[np.ndarray, float]:
    """The smallest circle enclosing 2-D points (n, 2): (centre, radius).  Welzl's algorithm
    (iterative, on the points' convex hull, in a seeded random order).  Each loop jumps to its
    next point outside the circle (`_next_outside`, one array operation over the rest): the
    points it passes are inside, as the point-by-point loop would find them one at a time."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) > 3:
        with contextlib.suppress(QhullError):  # degenerate (collinear) input: keep all points
            pts = pts[ConvexHull(pts).vertices]
    pts = pts[np.random.default_rng(seed).permutation(len(pts))]
    if len(pts) == 1:
        return pts[0].copy(), 0.0
    c, r = _circle2(pts[0], pts[1])
    i = _next_outside(pts, c, r, 2, len(pts))
    while i < len(pts):
        c, r = pts[i].copy(), 0.0
        j = _next_outside(pts, c, r, 0, i)
        while j < i:
            c, r = _circle2(pts[i], pts[j])
            k = _next_outside(pts, c, r, 0, j)
            while k < j:
                c, r = _circle3(pts[i], pts[j], pts[k])
                k = _next_outside(pts, c, r, k + 1, j)
            j = _next_outside(pts, c, r, j + 1, i)
        i = _next_outside(pts, c, r, i + 1, len(pts))
    return c, r


WELZL_EPS = 1e-12  # a point this far outside the circle counts as on it


def _next_outside(pts: np.ndarray, c: np.ndarray, r: float, lo: int, hi: int) -> int:
    """The first index in [lo, hi) of a point outside the circle (c, r), else hi."""
    if lo >= hi:
        return hi
    d = pts[lo:hi] - c
    out = np.flatnonzero(np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) > r + WELZL_EPS)
    return lo + int(out[0]) if len(out) else hi


def _basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    return u, np.cross(d, u)


def _hull_points(points: np.ndarray) -> np.ndarray:
    if len(points) > 8:
        try:
            return points[ConvexHull(points).vertices]
        except QhullError:
            pass
    return points


def capsule_along(points: np.ndarray, d: np.ndarray) -> Capsule:
    """The smallest capsule with axis direction d (unit) that encloses the points."""
    u, v = _basis(d)
    c2, r = enclosing_circle(np.stack([points @ u, points @ v], axis=1))
    r *= 1.0 + 1e-9
    t = points @ d
    rho = np.hypot(points @ u - c2[0], points @ v - c2[1])
    s = np.sqrt(np.maximum(r * r - rho * rho, 0.0))
    ta, tb = float(np.min(t + s)), float(np.max(t - s))
    if tb - ta < 2 * MIN_HALF:  # any axial position in [tb, ta] covers all: centre a short one there
        mid = (ta + tb) / 2
        ta, tb = mid - MIN_HALF, mid + MIN_HALF
        # (the extra length keeps every point inside: it only lengthens the segment)
    base = c2[0] * u + c2[1] * v
    return Capsule(a=base + ta * d, b=base + tb * d, r=float(r))


def _axes(points: np.ndarray) -> list[np.ndarray]:
    out = [np.eye(3)[i] for i in range(3)]
    if len(points) >= 3:
        w, vecs = np.linalg.eigh(np.cov((points - points.mean(0)).T))
        out += [vecs[:, i] for i in np.argsort(w)[::-1]]
    uniq: list[np.ndarray] = []
    for d in out:
        d = d / np.linalg.norm(d)
        if all(abs(float(d @ e)) < 1 - 1e-6 for e in uniq):
            uniq.append(d)
    return uniq


def fit_one(points: np.ndarray, refine: bool = True) -> Capsule:
    """The smallest enclosing capsule over the candidate axes, the best axis then refined
    (Nelder-Mead over its two angles) if `refine`."""
    hull = _hull_points(points)
    best = min((capsule_along(hull, d) for d in _axes(points)), key=lambda c: c.volume)
    d0 = best.b - best.a
    if not refine or np.linalg.norm(d0) < 4 * MIN_HALF:
        return best
    d0 /= np.linalg.norm(d0)

    def direction(x: np.ndarray) -> np.ndarray:
        th, ph = x
        return np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])

    x0 = np.array([np.arccos(np.clip(d0[2], -1, 1)), np.arctan2(d0[1], d0[0])])
    res = minimize(lambda x: capsule_along(hull, direction(x)).volume, x0, method="Nelder-Mead",
                   options={"xatol": 1e-4, "fatol": 1e-10, "maxiter": 80})  # fmt: skip
    refined = capsule_along(hull, direction(res.x))
    return refined if refined.volume < best.volume else best


def fit_capsules(points: np.ndarray, max_capsules: int = MAX_CAPSULES) -> list[Capsule]:
    """One to `max_capsules` capsules that together enclose every point (n, 3): the slabs
    chosen with each slab's best candidate axis, then every chosen capsule's axis refined."""
    points = np.asarray(points, dtype=np.float64)
    best = [fit_one(points, refine=False)]
    parts_best = [points]
    if len(points) >= 8:
        w, vecs = np.linalg.eigh(np.cov((points - points.mean(0)).T))
        split_axes = [vecs[:, i] for i in np.argsort(w)[::-1]]  # slabs across each principal axis
        # a slab's capsule depends on its axis and bounds alone: fitted once, however many
        # cuts share it (3 or 4 slabs from the same 9 cuts share most of theirs)
        slabs: dict[tuple[int, float, float], Capsule] = {}
        for k in range(2, max_capsules + 1):
            trial, trial_parts = None, None
            for a, d in enumerate(split_axes):
                t = points @ d
                grid = np.quantile(t, np.linspace(0.1, 0.9, 17 if k == 2 else 9))
                for cuts in itertools.combinations(grid, k - 1):
                    edges = [-np.inf, *cuts, np.inf]
                    parts = [points[(t >= lo) & (t <= hi)] for lo, hi in itertools.pairwise(edges)]
                    if any(len(p) < 4 for p in parts):
                        continue
                    caps = []
                    for (lo, hi), p in zip(itertools.pairwise(edges), parts, strict=True):
                        key = (a, float(lo), float(hi))
                        if key not in slabs:
                            slabs[key] = fit_one(p, refine=False)
                        caps.append(slabs[key])
                    if trial is None or sum(c.volume for c in caps) < sum(c.volume for c in trial):
                        trial, trial_parts = caps, parts
            if trial is None or sum(c.volume for c in trial) > (1 - GAIN) * sum(c.volume for c in best):
                break
            best, parts_best = trial, trial_parts
    return [fit_one(p) for p in parts_best]


def coverage(points: np.ndarray, caps: list[Capsule], tol: float = 1e-7) -> float:
    """The share of points inside (within tol of) at least one capsule."""
    inside = np.zeros(len(points), dtype=bool)
    for c in caps:
        inside |= segment_distance(points, c.a, c.b) <= c.r + tol
    return float(inside.mean())


def union_volume(caps: list[Capsule], samples: int = 200_000, seed: int = 0) -> float:
    """The volume of the capsules' union [m^3], by Monte Carlo in their bounding box."""
    lo = np.min([np.minimum(c.a, c.b) - c.r for c in caps], axis=0)
    hi = np.max([np.maximum(c.a, c.b) + c.r for c in caps], axis=0)
    p = np.random.default_rng(seed).uniform(lo, hi, (samples, 3))
    inside = np.zeros(samples, dtype=bool)
    for c in caps:
        inside |= segment_distance(p, c.a, c.b) <= c.r
    return float(inside.mean() * np.prod(hi - lo))


def hull_volume(points: np.ndarray) -> float:
    """The volume of the points' convex hull [m^3] (0 when they span no volume)."""
    try:
        return float(ConvexHull(points).volume)
    except QhullError:
        return 0.0
