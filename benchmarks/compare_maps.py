"""Compare Reach-Ability maps built on two devices (e.g. CPU and GPU) cell by cell.

python benchmarks/compare_maps.py DIR_A DIR_B     (files none.h5, case1.h5, case2.h5)
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from lmjx.mapfile.read import load_map


def main(a: str, b: str) -> None:
    for name in ("none", "case1", "case2"):
        pa, pb = Path(a) / f"{name}.h5", Path(b) / f"{name}.h5"
        if not (pa.exists() and pb.exists()):
            print(f"{name}: missing ({pa.exists()=}, {pb.exists()=})")
            continue
        ra, rb = load_map(pa).reach, load_map(pb).reach
        same = float(np.mean(ra.labels == rb.labels))
        print(
            f"{name}: labels agree on {same * 100:.2f}% of {ra.labels.size} cells; "
            f"PM {ra.areas()['pm']:.4f} vs {rb.areas()['pm']:.4f} m^2, "
            f"NPM+PM {ra.areas()['npm_pm']:.4f} vs {rb.areas()['npm_pm']:.4f} m^2 "
            f"({ra.device} vs {rb.device})"
        )


if __name__ == "__main__":
    main(*sys.argv[1:3])
