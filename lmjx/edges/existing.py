"""What a build's `--out` already holds: the map this build would write, or something else.

`lmjx build-map` run twice with the same arguments (`make run` again) keeps the map the
first run wrote instead of computing it again, and refuses to replace any other file
without `--overwrite`.  A build is named by its plan (`build_plan`: the robot's model hash,
the failure, every parameter of the reach map and of the edges, the number of edges and the
seed), the record a partial build keeps in `<out>.partial/plan.json`; a finished map holds
the same values in its attributes, which `map_plan` reads back.  The version of lmjx that
wrote a map is not part of its plan.  Nothing here writes.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from lmjx import __version__
from lmjx.mapfile.bundle import BundleConfig
from lmjx.mapfile.h5 import h5open
from lmjx.mapfile.schema import READ_VERSIONS, SCHEMA, attr_str, config_from_attrs
from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.reach.reachability import ReachConfig

# ReachConfig fields that say how a map is computed, not what it holds
REACH_HOW = ("strategy", "chunk", "traced_locks")


def build_plan(robot: Robot, failure: Failure, reach_cfg: ReachConfig, config: BundleConfig) -> dict:
    """What a build computes (a resume must match it, and a map at --out must match it to be kept)."""
    reach = {k: v for k, v in asdict(reach_cfg).items() if k not in REACH_HOW}
    return _plain(
        {
            "lmjx_version": __version__,
            "robot_model_hash": robot.model_hash,
            "failure": failure.spec,
            "locked": [list(x) for x in failure.locked],
            "reach": reach,
            "edges": config.content(),
            "n": config.n_edges(),
        }
    )


def _plain(d: dict) -> dict:
    """`d` as JSON gives it back (tuples as lists), so plans compare whatever their source."""
    return json.loads(json.dumps(d, default=list))


def map_plan(path: str | Path) -> dict | str:
    """The plan of the finished map at `path` (without `lmjx_version`), or, for any other
    file, what it holds in a few words."""
    try:
        with h5open(path, "r") as f:
            a = f.attrs
            if attr_str(a.get("schema", "")) != SCHEMA:
                return "a file that is not an lmjx map"
            version = int(a.get("schema_version", -1))
            if version not in READ_VERSIONS:
                return f"a map of schema version {version}, which this lmjx does not read"
            if "edges" not in f or attr_str(a.get("contents", "")) != "reach+edges":
                return "a map without edges (lmjx reach --out)"
            reach = config_from_attrs(ReachConfig, dict(f["reach"].attrs))
            edges = config_from_attrs(BundleConfig, dict(f["edges"].attrs))
            locked = [[int(j), float(x)] for j, x in zip(a["locked_joints"], a["locked_angles"], strict=True)]
            return _plain(
                {
                    "robot_model_hash": attr_str(a["robot_model_hash"]),
                    "failure": attr_str(a["failure"]),
                    "locked": locked,
                    "reach": {k: v for k, v in asdict(reach).items() if k not in REACH_HOW},
                    "edges": edges.content(),
                    "n": int(f["edges"].attrs["edges_sampled"]),
                }
            )
    except (OSError, KeyError, ValueError, TypeError) as e:
        return f"a file lmjx cannot read as a map ({type(e).__name__})"


def difference(path: str | Path, plan: dict) -> str | None:
    """None when the file at `path` is the finished map of `plan` (`build_plan`), else what
    it holds instead, in words (for a one-line refusal)."""
    there = map_plan(path)
    if isinstance(there, str):
        return there
    if there["robot_model_hash"] != plan["robot_model_hash"]:
        return "a map of another robot or robot model"
    if there["failure"] != plan["failure"] or there["locked"] != plan["locked"]:
        return f"a map of the failure {there['failure']}"
    if there["n"] != plan["n"]:
        return f"a map of {there['n']:,} sampled edges, not {plan['n']:,}"
    for part in ("reach", "edges"):
        mine = {k: v for k, v in plan[part].items() if not (part == "edges" and k == "edges")}
        for key, value in mine.items():
            if there[part].get(key) != value:
                return f"a map built with {part} {key} {there[part].get(key)}, not {value}"
    return None
