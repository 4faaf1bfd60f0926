"""`lmjx view`: an interactive 3D view in the browser of a map, a scene file, a trial or an
evaluation (viser: a server on this machine, drawn by the browser, no OpenGL needed here;
through an SSH tunnel from a GPU server too), or the same scene as one self-contained HTML
file with its title and legend."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from lmjx.cli.common import _add_robot, _positive_int


def _cell(text: str) -> tuple[int, int]:
    try:
        iy, ix = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"give the cell as IY,IX (two whole numbers), got {text!r}") from None
    if iy < 0 or ix < 0:
        raise argparse.ArgumentTypeError(f"cell indices are at least 0, got {text}")
    return iy, ix


def _port(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a port number") from None
    if not 0 <= v <= 65535:
        raise argparse.ArgumentTypeError(f"{v} is out of range; give 1 to 65535 (0: any free port)")
    return v


def _moment(text: str) -> str:
    """--at: start, end, or a time in seconds (a finite number, at least 0), kept as given."""
    import math

    if text in ("start", "end"):
        return text
    try:
        seconds = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"give start, end or a time in seconds, got {text!r}") from None
    if not (math.isfinite(seconds) and seconds >= 0):
        raise argparse.ArgumentTypeError(f"a time in seconds is a finite number at least 0, got {text}")
    return text


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    from lmjx.view.options import DRAWINGS, QUANTITIES

    p = sub.add_parser(
        "view",
        help="an interactive 3D view in the browser of a map, a scene file, a trial or an evaluation",
        description="Serve an interactive 3D view on this machine and open it in any browser (through an SSH tunnel "
        "from a remote server: ssh -L 8080:localhost:8080 HOST). A map (.h5): the table, the arm in its failure's "
        "park pose, the reach map's cells (PM green, NPM blue, unreachable grey, as lmjx reach --png draws them) "
        "and, for a selected cell (click it), the edges whose arm acts there. A scene file (.toml): the table, the "
        "target, the movable boxes and cylinders, the fixed obstacles and the goal region before planning; with "
        "--map, the reach cells under them. A trial (lmjx plan --json output, or --trial of an evaluation's "
        "results.json): replayed in its scene, with a time slider. An evaluation folder: its report and each of its "
        "trials. Every page has a title and a legend of its colours. Needs viser: pip install -e '.[view]'.",
    )
    p.add_argument(
        "path",
        help="a map file (.h5), a scene file (.toml), a trial record or results.json (.json), or an evaluation folder",
    )
    p.add_argument(
        "--trial", metavar="F/S/ASM/SEED", help="the trial of results.json to show, e.g. case2/1/greedy/1000"
    )
    p.add_argument(
        "--map",
        action="append",
        metavar="PATH",
        help="a trial's map (repeat for an evaluation of several failures; default: maps/<failure>.h5, "
        "where lmjx build-map writes it); a scene file's: its reach cells are drawn and its goal checked against it",
    )
    p.add_argument(
        "--cell",
        type=_cell,
        metavar="IY,IX",
        help="a map: the cell selected first (default: the cell the most edges act over)",
    )
    p.add_argument(
        "--edges",
        type=_positive_int,
        default=100,
        metavar="N",
        help="a map: edges drawn over the selected cell, at most (default 100; a slider changes it)",
    )
    p.add_argument("--color-by", choices=tuple(QUANTITIES), default="duration", help="a map: the edges' colour")
    p.add_argument(
        "--draw",
        choices=("paths", "arm"),
        default="paths",
        help=f"a map: each edge's interaction-point path, or the arm swept along it (default paths; "
        f"the GUI offers both: {', '.join(DRAWINGS)})",
    )
    p.add_argument(
        "--at",
        type=_moment,
        default="start",
        metavar="start|end|SECONDS",
        help="a trial: the moment shown first (default start)",
    )
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=_port, default=8080, help="port to serve on (default 8080; 0: any free port)")
    p.add_argument(
        "--html",
        metavar="OUT.html",
        help="write the scene to one self-contained HTML file that opens offline (no server), and exit",
    )
    _add_robot(p, from_map=True)
    p.add_argument("--json", action="store_true", help="print what is served or written as JSON on stdout")
    p.set_defaults(run=cmd_view)
    return p


def _kind(path: Path) -> str:
    from lmjx.errors import ConfigError

    if not path.exists():
        raise ConfigError(f"{path} does not exist")
    if path.is_dir():
        if not (path / "results.json").is_file():
            raise ConfigError(
                f"{path} is a folder without results.json: not an evaluation folder (lmjx evaluate --out)"
            )
        return "evaluation"
    import h5py

    if path.suffix.lower() in (".h5", ".hdf5") or h5py.is_hdf5(str(path)):
        return "map"
    if path.suffix.lower() == ".json":
        return "trial"
    if path.suffix.lower() == ".toml":
        return "scene"
    raise ConfigError(
        f"{path} is not an lmjx map (.h5), a scene file (.toml), a trial record (.json) or an evaluation folder"
    )


def _say(line: str) -> None:
    print(f"lmjx view: {line}", file=sys.stderr)


def _load(args: argparse.Namespace, kind: str, path: Path) -> tuple[Any, str]:
    """Everything the view needs, read and checked before a server starts (a mistake is a
    one-line error): the opened map, the replayed trial, or the evaluation's records."""
    from lmjx.errors import ConfigError

    if kind == "map":
        from lmjx.view.mapdata import MapData

        if args.trial is not None:
            raise ConfigError("--trial picks a trial of an evaluation (results.json or its folder), not of a map")
        data = MapData(path, _robot(args))
        if args.cell is not None and not (args.cell[0] < data.ny and args.cell[1] < data.nx):
            data.close()
            raise ConfigError(f"--cell {args.cell[0]},{args.cell[1]} is off the map's {data.ny} x {data.nx} cells")
        return data, f"map {path}"
    if kind == "scene":
        return _scene(args, path), f"scene {path}"
    if kind == "trial":
        from lmjx.view.trialrecord import read_trial

        return _replayed(args, read_trial(path, args.trial)), f"trial {path}"
    from lmjx.view.trialrecord import pick_trial, results_records

    records = results_records(path / "results.json")
    picked = _replayed(args, pick_trial(records, args.trial, path / "results.json")) if args.trial else None
    return picked, f"evaluation {path}"


def _scene(args: argparse.Namespace, path: Path) -> dict[str, Any]:
    """A scene file's task, read and checked as lmjx plan --scene checks it (with --map: its
    goal against the map's reach), the arm's pose and the map's reach cells."""
    from lmjx.errors import ConfigError
    from lmjx.sim.scenefile import load_scene

    if args.trial is not None:
        raise ConfigError("--trial picks a trial of an evaluation (results.json or its folder), not of a scene file")
    if args.map and len(args.map) > 1:
        raise ConfigError("a scene file is drawn over one map: give --map once")
    if not args.map:
        robot = _robot(args)
        if robot is None:
            from lmjx.model.robot import load_robot

            robot = load_robot("panda")
        return {"task": load_scene(path, robot), "robot": robot, "q": robot.ready.copy(), "reach": None, "failure": ""}
    from lmjx.mapfile.read import load_map
    from lmjx.planner.clearance import park_pose

    with load_map(args.map[0], _robot(args), with_edges=False) as m:
        assert m.robot is not None
        if m.reach is None:
            raise ConfigError(f"{m.path} holds no reach map; give a map from lmjx build-map or lmjx reach")
        task = load_scene(path, m.robot, m)
        return {"task": task, "robot": m.robot, "q": park_pose(m.robot, m.failure), "reach": m.reach,
                "failure": m.failure.spec}  # fmt: skip


def _replayed(args: argparse.Namespace, record: Any) -> Any:
    from lmjx.mapfile.read import load_map
    from lmjx.view.replay import replay
    from lmjx.view.trialrecord import map_for, trial_task

    m = load_map(map_for(record, args.map), _robot(args), lazy=True)
    assert m.robot is not None
    trial_task(record, m.robot)  # a record whose scene cannot be rebuilt: its one line, before any other
    _say(f"replaying trial {record.key} on {m.path}")
    rep = replay(m.robot, m, record, say=_say)
    bad = rep.first_disagreement()
    if bad is not None:
        _say(f"the replay parts from the record at action {bad.index + 1} (another map or version of lmjx?)")
    elif not rep.complete:
        _say(f"the replay stops at action {len(rep.actions) + 1}: no transit to its edge (another map?)")
    return rep


def _draw(server: Any, args: argparse.Namespace, kind: str, path: Path, loaded: Any) -> Any:
    """Draw what `_load` read into `server`; returns the view (its `tick` animates)."""
    from lmjx.view.replay import frame_at

    if kind == "map":
        from lmjx.view.map import MapView, MapViewSettings
        from lmjx.view.options import DRAWINGS

        draw = DRAWINGS[1] if args.draw == "arm" else DRAWINGS[0]
        settings = MapViewSettings(cap=args.edges, quantity=args.color_by, drawing=draw, select=args.cell)
        return MapView(server, loaded, settings)
    if kind == "scene":
        from lmjx.view.scene import SceneView

        return SceneView(server, loaded["task"], loaded["robot"], loaded["q"], loaded["reach"], str(path),
                         loaded["failure"])  # fmt: skip
    if kind == "trial":
        from lmjx.view.trial import TrialView

        return TrialView(server, loaded, at=frame_at(args.at, len(loaded.frames)))
    from lmjx.view.evaluation import EvaluationView

    view = EvaluationView(server, path, args.map, say=_say)
    if loaded is not None:
        view.show(loaded, at=args.at)
    return view


def _robot(args: argparse.Namespace):
    from lmjx.cli.common import _load_robot

    return _load_robot(args) if args.robot else None


def cmd_view(args: argparse.Namespace) -> int:
    from lmjx.view.server import check_html_path, check_port, require_viser, start_server, stop_server, url_of

    require_viser()
    path = Path(args.path)
    kind = _kind(path)
    if args.html is not None:
        check_html_path(args.html)
    else:
        check_port(args.host, args.port)
    loaded, what = _load(args, kind, path)
    server = (
        start_server("127.0.0.1", 0, "lmjx") if args.html is not None else start_server(args.host, args.port, "lmjx")
    )
    try:
        view = _draw(server, args, kind, path, loaded)
        if args.html is not None:
            from lmjx.view.server import write_html
            from lmjx.view.trial import TrialView

            serializer = server.get_scene_serializer()
            trial = view if isinstance(view, TrialView) else getattr(view, "trial", None)
            if trial is not None:  # the trial plays back on viser's own timeline
                trial.record_playback(serializer)
            size = write_html(serializer, args.html, getattr(view, "page", None))
            summary = {"kind": kind, "shows": what, "html": str(args.html), "bytes": size}
            print(
                json.dumps(summary, indent=2) if args.json else f"{what}: written to {args.html} ({size / 1e6:.1f} MB)"
            )
            return 0
        url = url_of(server)
        if args.json:
            print(
                json.dumps({"kind": kind, "shows": what, "url": url, "port": server.get_port()}, indent=2), flush=True
            )
        _say(f"{what}: open {url} in a browser (Ctrl-C to stop)")
        from lmjx.view.server import serve_until_interrupted

        try:
            serve_until_interrupted(server, getattr(view, "tick", None))
        except KeyboardInterrupt:
            _say("stopped")
        return 0
    finally:
        stop_server(server)
