"""Whether two lmjx map files hold the same datasets, exactly (run records aside: times,
device, the lmjx version).  Reads slice by slice, so maps larger than memory compare too.

    python benchmarks/same_map.py A.h5 B.h5      # prints the differences; exit 1 if any
"""

from __future__ import annotations

import sys

import h5py
import numpy as np

SLICE = 1 << 24  # elements per comparison
RUN_ATTRS = {"seconds", "compile_seconds", "kernel_seconds", "device", "devices", "processes", "lmjx_version",
             "rollout_seconds", "write_seconds", "finish_seconds", "edge_steps_per_s", "states_per_s"}  # fmt: skip


def differences(a: str, b: str) -> list[str]:
    out: list[str] = []
    with h5py.File(a, "r") as fa, h5py.File(b, "r") as fb:

        def walk(ga: h5py.Group, gb: h5py.Group, where: str) -> None:
            for k in sorted(set(ga.attrs) | set(gb.attrs)):
                if k in RUN_ATTRS or k.endswith("_seconds"):
                    continue
                va, vb = np.asarray(ga.attrs.get(k)), np.asarray(gb.attrs.get(k))
                if not np.array_equal(va, vb, equal_nan=va.dtype.kind == "f" and vb.dtype.kind == "f"):
                    out.append(f"{where} attribute {k}: {va!r} != {vb!r}")
            for k in sorted(set(ga) | set(gb)):
                if k not in ga or k not in gb:
                    out.append(f"{where}/{k} only in one file")
                elif isinstance(ga[k], h5py.Group):
                    walk(ga[k], gb[k], f"{where}/{k}")
                else:
                    da, db = ga[k], gb[k]
                    if da.shape != db.shape or da.dtype != db.dtype:
                        out.append(f"{where}/{k}: {da.shape} {da.dtype} != {db.shape} {db.dtype}")
                        continue
                    if da.shape == ():
                        same = da[()] == db[()]
                    else:
                        step = max(1, SLICE // max(1, int(np.prod(da.shape[1:]))))
                        same = all(
                            np.array_equal(da[i : i + step], db[i : i + step], equal_nan=da.dtype.kind == "f")
                            for i in range(0, da.shape[0], step)
                        )
                    if not same:
                        out.append(f"{where}/{k} differs")

        walk(fa, fb, "")
    return out


if __name__ == "__main__":
    diffs = differences(sys.argv[1], sys.argv[2])
    print(f"{sys.argv[1]} vs {sys.argv[2]}: " + ("the same datasets" if not diffs else "; ".join(diffs)))
    sys.exit(1 if diffs else 0)
