"""Compare the edge bundles of two map files built with the same command and seed on two
devices (e.g. CPU and GPU): which sampled edges each kept, and how close their states are.

    python benchmarks/compare_edges.py A.h5 B.h5
"""

from __future__ import annotations

import sys

import numpy as np

from lmjx.mapfile.read import load_map


def main(a: str, b: str) -> None:
    ea, eb = load_map(a).edges, load_map(b).edges
    assert ea is not None and eb is not None, "both files need edges"
    # The same seed samples the same twists: a twist identifies a sampled edge.
    key_a = {tuple(np.round(t, 6)): i for i, t in enumerate(ea.twist)}
    key_b = {tuple(np.round(t, 6)): i for i, t in enumerate(eb.twist)}
    both = key_a.keys() & key_b.keys()
    worst_q = worst_p = 0.0
    for k in both:
        sa, sb = ea.edge(key_a[k]), eb.edge(key_b[k])
        if len(sa["q"]) != len(sb["q"]):
            worst_q = float("inf")
            continue
        worst_q = max(worst_q, float(np.abs(sa["q"] - sb["q"]).max()))
        worst_p = max(worst_p, float(np.abs(sa["p"] - sb["p"]).max()))
    union = len(key_a.keys() | key_b.keys())
    print(
        f"valid edges: {ea.n_edges} vs {eb.n_edges}; kept by both {len(both)} "
        f"({len(both) / max(union, 1) * 100:.2f} % of either); on edges kept by both, largest difference: "
        f"q {worst_q:.2e} rad, p {worst_p:.2e} m ({ea.device} vs {eb.device})"
    )
    print(f"rejections: {ea.rejected}\n        vs  {eb.rejected}")


if __name__ == "__main__":
    main(*sys.argv[1:3])
