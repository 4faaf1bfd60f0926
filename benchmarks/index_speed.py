"""Time the map's spatial index on the device (`lmjx.edges.index`) on a built map's states.

    python benchmarks/index_speed.py MAP.h5 [--batch EDGES] [--repeat N] [--check]

The map's valid edges are indexed in batches of `--batch` consecutive edges (default 16,384,
about a packing unit's valid edges of case 2), as the build's packers index them, after one
batch that compiles.  Printed: the programs' compile time, then per repeat the seconds, the
states per second, the passes (and the extra passes of blocks with more items than a pass
holds) and the borderline items settled on the host; the device.  `--check` compares every
batch's pairs with the numpy reference (tests/reference_index.py), pair for pair.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from lmjx.edges.index import Grid, arm_index, arm_index_pairs, index_totals
from lmjx.mapfile.read import load_map
from lmjx.model.robot import load_robot
from lmjx.runtime.batching import device_description


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("map")
    ap.add_argument("--batch", type=int, default=16_384, help="valid edges per batch")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--check", action="store_true", help="compare every batch with the numpy reference")
    args = ap.parse_args()
    m = load_map(args.map)
    robot = m.robot or load_robot()
    reach, e = m.reach, m.edges
    q = np.asarray(e.q, np.float32)
    length = np.asarray(e.length)
    first = np.concatenate([[0], np.cumsum(length)])
    batches = [(a, min(a + args.batch, len(length))) for a in range(0, len(length), args.batch)]
    grid = Grid.of(reach)
    index = arm_index(robot, grid.nx, grid.ny, grid.cell)
    t0 = time.perf_counter()
    index.compile()
    print(f"{device_description()}: {len(length):,} edges, {len(q):,} states in {len(batches)} batches; "
          f"compile {time.perf_counter() - t0:.2f} s; shape {index.shape}", flush=True)  # fmt: skip
    height = e.config.index_height

    def batch(a: int, b: int):
        return arm_index_pairs(reach, robot, q[first[a] : first[b]], length[a:b], height)

    batch(*batches[0])  # the first call's loads and warm-ups
    for i in range(args.repeat):
        before = index_totals()
        t = time.perf_counter()
        pairs = [batch(a, b) for a, b in batches]
        s = time.perf_counter() - t
        done = index_totals(before)
        print(f"run {i}: {s:.3f} s, {len(q) / s / 1e6:.2f} M states/s, {sum(len(c) for c, _ in pairs):,} pairs, "
              f"passes {done['passes']} (extra {done['extra_passes']}), borderline {done['borderline']}, "
              f"blocks settled on the host {done['host_blocks']}", flush=True)  # fmt: skip
    if args.check:
        sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
        from reference_index import reference_pairs

        for (a, b), got in zip(batches, pairs, strict=True):
            want = reference_pairs(reach, robot, q[first[a] : first[b]], length[a:b], height)
            same = np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
            print(f"edges [{a}, {b}): {len(want[0]):,} pairs, {'the same' if same else 'DIFFERENT'}", flush=True)
            if not same:
                sys.exit(1)


if __name__ == "__main__":
    main()
