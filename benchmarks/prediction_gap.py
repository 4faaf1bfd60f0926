"""What Greedy and Lazy expected of their picks against what came of them in the "real" world.

Reads `lmjx evaluate` results (results.json, records with `predicted_score_m` and
`score_after_m` per action) and prints, over every action that has a score before it (the
previous action's `score_after_m`): the gain the planner predicted (before - predicted), the
gain that came (before - after), the gap (after - predicted), and how often a predicted gain of
5 mm or more came true.  `--band LO HI` also reports the actions taken with the score before
between LO and HI metres (e.g. the hard tunnel's opening, 0.11-0.16 m).

    python benchmarks/prediction_gap.py results.json [more.json ...] [--band 0.11 0.16]
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

GAIN = 0.005  # [m] a predicted or real gain that counts


def rows(records: list[dict]) -> np.ndarray:
    """(n, 3): score before, predicted, after, for each action with all three."""
    out = []
    for t in sorted(records, key=lambda r: (r["failure"], r["scenario"], r["asm"], r["seed"])):
        before = None
        for s in t["steps"]:
            after = s.get("score_after_m")
            if after is None:
                continue
            if before is not None and s.get("predicted_score_m") is not None:
                out.append((before, s["predicted_score_m"], after))
            before = after
    return np.array(out, dtype=float).reshape(-1, 3)


def report(a: np.ndarray, label: str) -> str:
    if not len(a):
        return f"{label}: no action with a prediction and a score before it"
    before, pred, after = a.T
    hoped = before - pred >= GAIN
    return (
        f"{label}: {len(a)} actions; predicted gain median {np.median(before - pred) * 1000:.1f} mm, "
        f"real gain median {np.median(before - after) * 1000:.1f} mm; gap (after - predicted) median "
        f"{np.median(after - pred) * 1000:.1f} mm, p90 {np.percentile(after - pred, 90) * 1000:.1f} mm, "
        f"mean |gap| {np.mean(np.abs(after - pred)) * 1000:.1f} mm; predicted to gain >= {GAIN * 1000:.0f} mm: "
        f"{hoped.sum()}, of those gained >= {GAIN * 1000:.0f} mm {(hoped & (before - after >= GAIN)).sum()}, "
        f"lost >= {GAIN * 1000:.0f} mm {(hoped & (after - before >= GAIN)).sum()}; the pick not predicted to "
        f"gain at all (Greedy: none of its candidates was; Lazy: none it tried): {(pred >= before).sum()}"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", help="results.json files of `lmjx evaluate`")
    ap.add_argument("--band", nargs=2, type=float, metavar=("LO", "HI"), help="also the actions taken from there")
    args = ap.parse_args(argv)
    records = []
    for path in args.results:
        try:
            with open(path) as f:
                records += json.load(f)
        except (OSError, ValueError) as e:
            print(f"prediction_gap: cannot read {path}: {e}", file=sys.stderr)
            return 2
    a = rows(records)
    print(report(a, "every action"))
    if args.band:
        lo, hi = args.band
        print(report(a[(a[:, 0] > lo) & (a[:, 0] < hi)], f"score before in {lo}-{hi} m"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
