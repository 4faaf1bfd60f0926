"""A map's content digest: SHA-256 over every dataset of its content (name, dtype, shape,
bytes): the robot, the reach map, the edges and their index.  Left out: the attributes (a
build's timings and device differ between builds of the same map) and what is derived from
the content (`DERIVED`: the push counts, computed from the edges on the build's platform), so
a map's digest is that of its content whichever lmjx version or platform added them.

Two builds with the same command and seed are the same map when their digests agree; an
evaluation split across machines or resumed on another one continues only on maps with the
digest it recorded (docs/evaluation/README.md lists the present runs' digests).

    python benchmarks/map_digest.py [-v] maps/case1.h5 maps/case2.h5     (-v: each dataset's too)
"""

from __future__ import annotations

import hashlib
import sys

import h5py
import numpy as np

ROWS = 1 << 20  # rows read at a time
DERIVED = ("edges/push",)  # groups derived from the content, not hashed


def _bytes(a: np.ndarray) -> bytes:
    """An array's content; strings and other objects by value (their buffer holds pointers)."""
    if a.dtype.kind != "O":
        return np.ascontiguousarray(a).tobytes()
    return b"\0".join(x if isinstance(x, bytes) else repr(x).encode() for x in a.ravel())


def digest(path: str, each: dict | None = None) -> tuple[str, int]:
    """(hex digest, datasets hashed) of the map at `path`; `each` gets every dataset's own."""
    h, names = hashlib.sha256(), []
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: names.append(name) if isinstance(obj, h5py.Dataset) else None)
        names = [n for n in names if not any(n == d or n.startswith(d + "/") for d in DERIVED)]
        for name in sorted(names):
            ds = f[name]
            h.update(f"{name}|{ds.dtype.str}|{ds.shape}".encode())
            rows = [ds[()]] if not ds.shape else (ds[i : i + ROWS] for i in range(0, ds.shape[0], ROWS))
            one = hashlib.sha256()
            for block in rows:
                b = _bytes(np.asarray(block))
                h.update(b)
                one.update(b)
            if each is not None:
                each[name] = one.hexdigest()[:16]
    return h.hexdigest(), len(names)


if __name__ == "__main__":
    verbose = "-v" in sys.argv[1:]
    paths = [a for a in sys.argv[1:] if a != "-v"]
    if not paths:
        sys.exit(__doc__.split("\n\n")[-1].strip())
    for p in paths:
        each: dict[str, str] = {}
        d, n = digest(p, each)
        print(f"{d}  {p}  ({n} datasets)", flush=True)
        if verbose:
            print("\n".join(f"  {v}  {k}" for k, v in each.items()), flush=True)
