"""The speed-up of a build on every GPU over one GPU, from the `--json` outputs of repeated
runs: each run's seconds after compilation and to the finished file, then the ratios of the
medians, the worst pairing, and the best.  A file is named RUN_TAG.json: the runs of one RUN
(a 1-GPU build, `--no-shard`, and an all-GPU build made one after the other) are paired.

    for r in 1 2 3; do
      lmjx build-map --failure case2 --edges 5000000 --no-shard --out a.h5 --json > out/s5m_${r}_1gpu.json
      lmjx build-map --failure case2 --edges 5000000 --out b.h5 --json > out/s5m_${r}_all.json
    done
    python benchmarks/speedup.py out/s5m_*.json
"""

from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path


def load(path: Path) -> dict | None:
    """The build's edge figures (a JSON file may carry a line of other output before it);
    None for a run that wrote none (it failed or timed out)."""
    text = path.read_text()
    try:
        return json.JSONDecoder().raw_decode(text[text.index("{") :])[0]["edges"]
    except (ValueError, KeyError):
        return None


def main(paths: list[str]) -> int:
    if not paths:
        print(__doc__.strip().splitlines()[-1].strip(), file=sys.stderr)
        return 2
    by_run: dict[str, dict[int, tuple[float, float]]] = {}  # "speedup5m_2": {GPUs: figures}
    for p in sorted(paths):
        e = load(Path(p))
        if e is None:
            print(f"{Path(p).name}: no build figures (the run failed?), left out", file=sys.stderr)
            continue
        devices = int(e["devices"])
        figures = (float(e["seconds"]), float(e["edges_wall_seconds"]))
        by_run.setdefault(Path(p).stem.rsplit("_", 1)[0], {})[devices] = figures
        print(f"{Path(p).name}: {devices} GPU(s), {e['seconds']:.2f} s after compilation, "
              f"{e['edges_wall_seconds']:.2f} s to the file, {e['edges_valid']:,} valid edges")  # fmt: skip
    runs: dict[int, list[tuple[float, float]]] = {}  # GPUs: every run's figures
    for r in by_run.values():
        for devices, figures in r.items():
            runs.setdefault(devices, []).append(figures)
    if 1 not in runs or len(runs) < 2:
        print("need runs on 1 GPU and on more", file=sys.stderr)
        return 2
    most = max(runs)
    pairs = [(r[1], r[most]) for r in by_run.values() if 1 in r and most in r]  # runs made one after the other
    for i, what in enumerate(("after compilation", "to the finished file")):
        print(f"speed-up {what}, run by run: " + ", ".join(f"{a[i] / b[i]:.2f}x" for a, b in pairs))
    for i, what in enumerate(("after compilation", "to the finished file")):
        one = [r[i] for r in runs[1]]
        many = [r[i] for r in runs[most]]
        print(f"{what}: 1 GPU median {statistics.median(one):.2f} s ({len(one)} runs), "
              f"{most} GPUs median {statistics.median(many):.2f} s ({len(many)} runs): "
              f"speed-up {statistics.median(one) / statistics.median(many):.2f}x median, "
              f"{min(one) / max(many):.2f}x worst, {max(one) / min(many):.2f}x best")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
