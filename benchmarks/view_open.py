"""How long `lmjx view MAP` takes to open a map and show a cell's edges, on this machine.

The view reads, at opening, the map's header, its reach map and the spatial index's offsets;
a selected cell's slice of the index, the per-edge quantities its colours need and the
states of the edges it draws are read when the cell is selected.  This times each step as
the view runs them (no browser: what the server builds and would send), from a fresh
process, the median of --repeats runs:

* open: `MapData(path)` (header, reach map, index offsets);
* scene: the viser server started and the map view drawn: table, arm, cells, and the cell
  the most edges act over selected, its edges read and drawn (--edges of them, the view's default 100);
* select: another cell selected (the second busiest), its edges read and drawn;
* load_map: for comparison, `lmjx.load_map(path, lazy=True)` (what the planner reads: the
  whole index and every per-edge array), which grows with the number of edges.

    python benchmarks/view_open.py maps/case2_1m.h5 [--edges 100] [--repeats 3] [--json OUT]

Acceptance: open + scene within 5 s on the 2-core CPU for the 1,000,000-edge map.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ONE_RUN = r"""
import json, sys, time
t0 = time.perf_counter()
from lmjx.view.mapdata import MapData
from lmjx.view.map import MapView, MapViewSettings
from lmjx.view.server import start_server, stop_server
t_import = time.perf_counter()
data = MapData(sys.argv[1])
t_open = time.perf_counter()
server = start_server("127.0.0.1", 0, "lmjx")
view = MapView(server, data, MapViewSettings(cap=int(sys.argv[2])))
t_scene = time.perf_counter()
counts = data.edge_count().ravel()
second = int(counts.argsort()[-2]) if counts.size > 1 else 0
sel = view.select(*divmod(second, data.nx))
t_select = time.perf_counter()
first = view.selected
stop_server(server)
t1 = time.perf_counter()
from lmjx.mapfile.read import load_map
with load_map(sys.argv[1], lazy=True):
    pass
t_load = time.perf_counter() - t1
print(json.dumps({
    "import_s": t_import - t0, "open_s": t_open - t_import, "scene_s": t_scene - t_open,
    "select_s": t_select - t_scene, "load_map_s": t_load, "edges": data.n_edges,
    "cell_edges": int(len(sel.ids)), "drawn": int(len(sel.drawn)),
}))
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map", help="a map file (lmjx build-map)")
    ap.add_argument("--edges", type=int, default=100, help="edges drawn over the selected cell (default 100)")
    ap.add_argument("--repeats", type=int, default=3, help="fresh processes timed (default 3)")
    ap.add_argument("--json", help="write the runs and their medians here")
    args = ap.parse_args()
    if not Path(args.map).is_file():
        print(f"view_open.py: error: {args.map} does not exist", file=sys.stderr)
        return 2
    env = {**os.environ, "JAX_PLATFORMS": os.environ.get("JAX_PLATFORMS", "cpu")}
    runs = []
    for _ in range(args.repeats):
        out = subprocess.run([sys.executable, "-c", ONE_RUN, args.map, str(args.edges)], env=env,
                             capture_output=True, text=True, check=False)  # fmt: skip
        if out.returncode != 0:
            print(out.stderr.strip().splitlines()[-1] if out.stderr.strip() else "failed", file=sys.stderr)
            return 1
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    keys = ("import_s", "open_s", "scene_s", "select_s", "load_map_s")
    median = {k: round(statistics.median(r[k] for r in runs), 3) for k in keys}
    median["open_and_show_s"] = round(median["open_s"] + median["scene_s"], 3)
    summary = {
        "map": args.map,
        "edges": runs[0]["edges"],
        "cell_edges": runs[0]["cell_edges"],
        "drawn": runs[0]["drawn"],
        "cpus": len(os.sched_getaffinity(0)),
        "date": time.strftime("%Y-%m-%d"),
        "median": median,
        "runs": runs,
    }
    print(json.dumps(summary, indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
