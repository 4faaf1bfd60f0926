"""3-D algebra on tuples of scalars, with constant folding.

A vector is a tuple of three scalars and a matrix a tuple of three row vectors.  A scalar is
either a Python float (a constant of the model: an offset, a locked joint's cosine) or an
array of any shape (one value per problem, or per capsule).  Keeping the coordinates apart
makes every batched operation elementwise over the batch: under `jax.vmap` the batch becomes
the minor axis, which vectorizes on a CPU and coalesces on a GPU, and XLA fuses a whole
solver iteration.  Arithmetic with the constants 0, 1 and -1 is folded away while tracing,
so zeros in the model's offsets and rotations cost nothing.

No I/O, no jit: helpers for kernels only.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp
import numpy as np

Scalar = float | jnp.ndarray
Vec = tuple[Scalar, Scalar, Scalar]
Mat = tuple[Vec, Vec, Vec]

_SNAP = 1e-9


def const(x: float) -> float:
    """A model constant as a Python float; values within 1e-9 of 0 or +-1 are snapped to them.

    (Rotation entries compiled from 8-digit quaternions miss 0 and 1 by ~1e-9; snapping
    lets the arithmetic with them fold away and moves nothing by more than a nanometre.)
    """
    x = float(x)
    if abs(x) < _SNAP:
        return 0.0
    if abs(abs(x) - 1.0) < _SNAP:
        return 1.0 if x > 0 else -1.0
    return x


def is_const(x: Scalar) -> bool:
    return isinstance(x, float)


def add(a: Scalar, b: Scalar) -> Scalar:
    if is_const(a) and is_const(b):
        return a + b
    if is_const(a) and a == 0.0:
        return b
    if is_const(b) and b == 0.0:
        return a
    return a + b


def neg(a: Scalar) -> Scalar:
    return -a


def sub(a: Scalar, b: Scalar) -> Scalar:
    if is_const(b) and b == 0.0:
        return a
    if is_const(a) and a == 0.0 and not is_const(b):
        return -b
    return a - b


def mul(a: Scalar, b: Scalar) -> Scalar:
    if is_const(a) and is_const(b):
        return a * b
    if is_const(b):
        a, b = b, a
    if is_const(a):
        if a == 0.0:
            return 0.0
        if a == 1.0:
            return b
        if a == -1.0:
            return -b
    return a * b


def sum_(terms: Sequence[Scalar]) -> Scalar:
    out: Scalar = 0.0
    for t in terms:
        out = add(out, t)
    return out


def cvec(v: np.ndarray) -> Vec:
    """Constant vector from numpy."""
    return (const(v[0]), const(v[1]), const(v[2]))


def cmat(m: np.ndarray) -> Mat:
    """Constant matrix from numpy."""
    return (cvec(m[0]), cvec(m[1]), cvec(m[2]))


def vadd(a: Vec, b: Vec) -> Vec:
    return (add(a[0], b[0]), add(a[1], b[1]), add(a[2], b[2]))


def vsub(a: Vec, b: Vec) -> Vec:
    return (sub(a[0], b[0]), sub(a[1], b[1]), sub(a[2], b[2]))


def vscale(s: Scalar, v: Vec) -> Vec:
    return (mul(s, v[0]), mul(s, v[1]), mul(s, v[2]))


def vdot(a: Vec, b: Vec) -> Scalar:
    return sum_([mul(a[0], b[0]), mul(a[1], b[1]), mul(a[2], b[2])])


def vcross(a: Vec, b: Vec) -> Vec:
    return (
        sub(mul(a[1], b[2]), mul(a[2], b[1])),
        sub(mul(a[2], b[0]), mul(a[0], b[2])),
        sub(mul(a[0], b[1]), mul(a[1], b[0])),
    )


def vwhere(c: jnp.ndarray, a: Vec, b: Vec) -> Vec:
    return tuple(jnp.where(c, x, y) for x, y in zip(a, b, strict=True))  # type: ignore[return-value]


def mvec(m: Mat, v: Vec) -> Vec:
    """m @ v."""
    return (vdot(m[0], v), vdot(m[1], v), vdot(m[2], v))


def mtvec(m: Mat, v: Vec) -> Vec:
    """m.T @ v."""
    return tuple(sum_([mul(m[i][j], v[i]) for i in range(3)]) for j in range(3))  # type: ignore[return-value]


def mcol(m: Mat, j: int) -> Vec:
    return (m[0][j], m[1][j], m[2][j])


def mmul(a: Mat, b: Mat) -> Mat:
    """a @ b."""
    return tuple(  # type: ignore[return-value]
        tuple(sum_([mul(a[i][k], b[k][j]) for k in range(3)]) for j in range(3)) for i in range(3)
    )


def axis_rotation(axis: np.ndarray, angle: Scalar) -> Mat:
    """Rotation by `angle` about the constant unit `axis` (Rodrigues).

    A constant angle (a locked joint) gives a constant matrix, folded into its neighbours.
    """
    axis = np.asarray(axis, dtype=np.float64)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    k2 = k @ k
    if is_const(angle):
        return cmat(np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * k2)
    s = jnp.sin(angle)
    c1 = 1.0 - jnp.cos(angle)
    return tuple(  # type: ignore[return-value]
        tuple(add(add(1.0 if i == j else 0.0, mul(const(k[i, j]), s)), mul(const(k2[i, j]), c1)) for j in range(3))
        for i in range(3)
    )


def select(index: jnp.ndarray, options: list[Scalar]) -> Scalar:
    """options[index] for a traced integer index; a constant when all options are one constant."""
    if all(is_const(o) for o in options) and len(set(options)) == 1:
        return options[0]
    out = options[-1]
    for k in range(len(options) - 2, -1, -1):
        out = jnp.where(index == k, options[k], out)
    return out


def select_vec(index: jnp.ndarray, options: list[Vec]) -> Vec:
    return tuple(select(index, [o[k] for o in options]) for k in range(3))  # type: ignore[return-value]


def to_array(x: Scalar, like: jnp.ndarray) -> jnp.ndarray:
    """A scalar as an array shaped and typed like `like` (constants are broadcast)."""
    if is_const(x):
        return jnp.full(jnp.shape(like), x, dtype=like.dtype)
    return jnp.broadcast_to(x, jnp.shape(like)).astype(like.dtype)


def stack_vec(v: Vec, like: jnp.ndarray) -> jnp.ndarray:
    """(..., 3) array from a vector."""
    return jnp.stack([to_array(c, like) for c in v], axis=-1)


def stack_mat(m: Mat, like: jnp.ndarray) -> jnp.ndarray:
    """(..., 3, 3) array from a matrix."""
    return jnp.stack([stack_vec(r, like) for r in m], axis=-2)


def quat_to_mat(quat: np.ndarray) -> np.ndarray:
    """MuJoCo (w, x, y, z) unit quaternion -> rotation matrix, numpy, for model constants."""
    w, x, y, z = np.asarray(quat, dtype=np.float64) / np.linalg.norm(quat)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
