"""Unrolled dense solves for the small systems of the IK (n <= 7 free joints).

Matrices are nested lists of scalars (see `math3`), so that a batched solve is fused
elementwise code rather than a library call on tiny matrices, and no array is stacked or
sliced inside a solver iteration.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp

from .math3 import Scalar, mul, sub


def cholesky_solve(h: Sequence[Sequence[Scalar]], g: Sequence[Scalar], eps: float = 1e-12) -> list[Scalar]:
    """Solve h x = g for a symmetric positive definite h (only h[i][j], j <= i, is read)."""
    n = len(g)
    low: list[list[Scalar]] = [[0.0] * n for _ in range(n)]
    inv_diag: list[Scalar] = [0.0] * n
    for j in range(n):
        s = h[j][j]
        for k in range(j):
            s = sub(s, mul(low[j][k], low[j][k]))
        d = jnp.sqrt(jnp.maximum(s, eps))
        low[j][j] = d
        inv_diag[j] = 1.0 / d
        for i in range(j + 1, n):
            t = h[i][j]
            for k in range(j):
                t = sub(t, mul(low[i][k], low[j][k]))
            low[i][j] = mul(t, inv_diag[j])
    y: list[Scalar] = []
    for i in range(n):
        t = g[i]
        for k in range(i):
            t = sub(t, mul(low[i][k], y[k]))
        y.append(mul(t, inv_diag[i]))
    x: list[Scalar] = [0.0] * n
    for i in reversed(range(n)):
        t = y[i]
        for k in range(i + 1, n):
            t = sub(t, mul(low[k][i], x[k]))
        x[i] = mul(t, inv_diag[i])
    return x


def cholesky_sqrt_det(h: Sequence[Sequence[Scalar]], eps: float = 1e-30) -> Scalar:
    """sqrt(det(h)) of a symmetric positive semi-definite h, as the product of the Cholesky
    diagonal (only h[i][j], j <= i, is read); 0 when h is singular."""
    n = len(h)
    low: list[list[Scalar]] = [[0.0] * n for _ in range(n)]
    out: Scalar = 1.0
    for j in range(n):
        s = h[j][j]
        for k in range(j):
            s = sub(s, mul(low[j][k], low[j][k]))
        d = jnp.sqrt(jnp.maximum(s, 0.0))
        out = mul(out, d)
        inv_d = 1.0 / jnp.maximum(d, eps)
        low[j][j] = d
        for i in range(j + 1, n):
            t = h[i][j]
            for k in range(j):
                t = sub(t, mul(low[i][k], low[j][k]))
            low[i][j] = mul(t, inv_d)
    return out
