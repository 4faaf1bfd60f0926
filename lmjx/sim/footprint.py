"""Footprints on the table top, for the layout and geometry checks: a box's is a rectangle
(its half sizes x, y turned by its yaw), an upright cylinder's a circle (its radius, at any
yaw).  Overlap tests between two footprints, each grown by a margin, batched over leading
axes: rectangle and rectangle by separating axes (`rect_rect`), circle and circle and
circle and rectangle exactly (the distance from the circle's centre to the other
footprint, `circle_circle`, `circle_rect`); `footprints_overlap` picks the test for two
objects.  Where a check takes polygons only, a cylinder's circumscribed square (its
circumscribing box's footprint, at its yaw) stands for it: conservative, since the square
holds the circle at any yaw.  Pure numpy; nothing here knows the scene."""

from __future__ import annotations

from typing import Protocol

import numpy as np


class Box(Protocol):
    """What a footprint needs of an object (`lmjx.sim.scenarios.Box`, `Cylinder`): its shape
    ("box" or "cylinder") and half sizes (a cylinder's: radius, radius, half height)."""

    @property
    def shape(self) -> str: ...

    @property
    def half(self) -> tuple[float, float, float]: ...


def rect_corners(half: np.ndarray, poses: np.ndarray, grow: float) -> np.ndarray:
    """Corners (..., 4, 2) of rectangles of half sizes half[..., :2] (grown by `grow`) at
    poses (..., 3) x, y, yaw, counter-clockwise."""
    half = np.asarray(half, np.float64)
    poses = np.asarray(poses, np.float64)
    hx, hy = half[..., 0] + grow, half[..., 1] + grow
    local = np.stack([np.stack([hx, hy], -1), np.stack([-hx, hy], -1), np.stack([-hx, -hy], -1),
                      np.stack([hx, -hy], -1)], -2)  # fmt: skip
    c, s = np.cos(poses[..., 2])[..., None], np.sin(poses[..., 2])[..., None]
    x = local[..., 0] * c - local[..., 1] * s
    y = local[..., 0] * s + local[..., 1] * c
    return np.stack([x + poses[..., None, 0], y + poses[..., None, 1]], -1)


def rect_rect(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether convex quadrilaterals a, b (..., 4, 2) overlap (separating axes; touching
    counts), (...,)."""
    separated = np.zeros(np.broadcast_shapes(a.shape, b.shape)[:-2], bool)
    for poly in (a, b):
        for i in range(4):
            edge = poly[..., (i + 1) % 4, :] - poly[..., i, :]
            axis = np.stack([-edge[..., 1], edge[..., 0]], -1)[..., None, :]
            pa, pb = (a * axis).sum(-1), (b * axis).sum(-1)
            separated |= (pa.max(-1) < pb.min(-1)) | (pb.max(-1) < pa.min(-1))
    return ~separated


def rect_distance(points: np.ndarray, half: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Distance (...,) from points (..., 2) to rectangles of half sizes half[..., :2] at
    poses (..., 3) x, y, yaw; 0 inside."""
    points, half, poses = (np.asarray(v, np.float64) for v in (points, half, poses))
    d = points - poses[..., :2]
    c, s = np.cos(poses[..., 2]), np.sin(poses[..., 2])
    lx, ly = d[..., 0] * c + d[..., 1] * s, -d[..., 0] * s + d[..., 1] * c
    ox = np.maximum(np.abs(lx) - half[..., 0], 0.0)
    oy = np.maximum(np.abs(ly) - half[..., 1], 0.0)
    return np.hypot(ox, oy)


def circle_circle(ca: np.ndarray, ra: float, cb: np.ndarray, rb: float, grow: float) -> np.ndarray:
    """Whether circles of radii ra, rb about centres ca, cb (..., 2), each grown by `grow`,
    overlap (touching counts), (...,)."""
    d = np.asarray(ca, np.float64)[..., :2] - np.asarray(cb, np.float64)[..., :2]
    return np.hypot(d[..., 0], d[..., 1]) <= ra + rb + 2 * grow


def circle_rect(center: np.ndarray, radius: float, half: np.ndarray, poses: np.ndarray, grow: float) -> np.ndarray:
    """Whether a circle of `radius` about `center` (..., 2) and rectangles of half sizes
    half[..., :2] at poses (..., 3), each grown by `grow` (the rectangle's half sizes, as
    `rect_corners` grows them), overlap (touching counts), (...,)."""
    grown = np.asarray(half, np.float64)[..., :2] + grow
    return rect_distance(np.asarray(center)[..., :2], grown, poses) <= radius + grow


def footprints_overlap(a: Box, pa: np.ndarray, b: Box, pb: np.ndarray, grow: float) -> np.ndarray:
    """Whether the footprints of objects a at poses pa (..., 3) and b at pb (..., 3), each
    grown by `grow`, overlap (touching counts), (...,): exact for every pair of shapes."""
    if a.shape == "box" and b.shape == "box":
        return rect_rect(rect_corners(np.asarray(a.half), pa, grow), rect_corners(np.asarray(b.half), pb, grow))
    if a.shape == "box":
        a, pa, b, pb = b, pb, a, pa
    pa, pb = np.asarray(pa, np.float64), np.asarray(pb, np.float64)
    if b.shape == "box":
        return circle_rect(pa[..., :2], a.half[0], np.broadcast_to(np.asarray(b.half), (*pb.shape[:-1], 3)), pb, grow)
    return circle_circle(pa, a.half[0], pb, b.half[0], grow)


def circle_inside(point: np.ndarray, center: tuple[float, float], radius: float) -> bool:
    """Whether a point (2,) lies in the circle of `radius` about `center`."""
    return bool(np.hypot(point[0] - center[0], point[1] - center[1]) <= radius)
