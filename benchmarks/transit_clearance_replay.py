"""Run the hard tunnel's CPU trial 2011 with `--push-weight 1` again, as `lmjx evaluate` runs
it, and print, for every transit, the real arm's least distance to the fixed obstacles and
the planned joint targets' (the "real" world's own model, kinematics only); for a transit
that touches one, its joints' tracking error and speed.  The ninth session's diagnostic of
the one transit that touched the roof (docs/EVALUATION.md, "The ninth session"):

    python benchmarks/transit_clearance_replay.py MAPS [--log FILE] [--law constant|retimed]

MAPS: the folder holding the CPU-built 1,000,000-edge case2.h5 the trial ran on.  It checks
the trial took the recorded edges (benchmarks/tunnel_push_weight2_h100_2026-11-26/
cpu_eval_w1.json); `--log`: every transit's figures as JSON too.  `--law constant` (the
default) plans and executes the transits at constant speed, as the ninth session did (the
trial is then the recorded one), and executes each transit a second time from the same state
as `lmjx.planner.timelaw.retime` times it (the present law: slowing to rest into sharp corners), its
least distance over the transit's physics steps printed beside ("retimed_min"; "real_min"
covers the same steps of the recorded execution; benchmarks/transit_retime_2026-11-27.json
measured each transit alone from its start with 0.3 s held after it, a stricter window: an
arm that ends at speed overshoots when held); `--law retimed` runs the trial as the present
code does (it takes other edges from the first transit with a sharp corner on).
"""

import argparse
import copy
import json
import tempfile
from pathlib import Path

import mujoco
import numpy as np

from lmjx.evaluation.evaluate import EvalConfig, evaluate, load_maps
from lmjx.model.robot import load_robot
from lmjx.planner.timelaw import retime
from lmjx.planner.transit import transit_velocities
from lmjx.sim.controls import controls
from lmjx.types import CONTROL_DT, Action, PlannerConfig

log = []
orig = executor.SimulatedRealWorld.execute


def execute(self, action):
    m = self.scene.model
    sc = self.scene.scenario
    fixed = [int(m.geom(b.name).id) for b in sc.fixed]
    arm = [g for g in range(m.ngeom) if self._robot_geom[g]]
    adr = [int(m.joint(n).qposadr[0]) for n in self.robot.joint_names]

    def least(d):
        best = (np.inf, "", "")
        for a in arm:
            for f in fixed:
                x = mujoco.mj_geomDistance(m, d, a, f, 0.1, None)
                if x < best[0]:
                    best = (x, m.geom(a).name or str(a), m.geom(f).name)
        return best

    d2 = mujoco.MjData(m)
    d2.qpos[:] = self.data.qpos
    planned = []
    for k in range(action.transit_steps):
        d2.qpos[adr] = action.q[k]
        mujoco.mj_kinematics(m, d2)
        mujoco.mj_collision(m, d2)
        planned.append(least(d2)[0])
    real = []
    sub = round(0.02 / m.opt.timestep)
    limit = action.transit_steps * sub
    track = []
    qadr = np.array(adr)
    vadr = np.array([int(m.joint(n).dofadr[0]) for n in self.robot.joint_names])

    def on_step(mod, d):
        if len(real) < limit:
            real.append(least(d))
            k = min(len(real) // sub, len(action.q) - 1)
            track.append(
                (
                    float(np.abs(d.qpos[qadr] - action.q[k]).max()),
                    float(np.abs(d.qvel[vadr]).max()),
                )
            )

    retimed_min = None
    if args.law == "constant" and action.transit_steps:  # the same transit, retimed, from the same state
        d3 = copy.deepcopy(self.data)
        q_now = self.data.qpos[qadr].copy()
        timed = retime(q_now, action.q[: action.transit_steps], CONTROL_DT)
        qd = transit_velocities(q_now, timed)
        alone = Action(edge=action.edge, q=timed, qd=qd, transit_steps=len(timed), via_park=False, route="x")
        retimed_min = np.inf
        for u in controls(alone, m.opt.timestep, 0.0):  # the transit's physics steps, as real_min
            d3.ctrl[:] = u
            mujoco.mj_step(m, d3)
            retimed_min = min(retimed_min, least(d3)[0])
        retimed_min = round(float(retimed_min), 4)
    self.on_step = on_step
    start = least(self.data)
    obs = orig(self, action)
    self.on_step = None
    i = int(np.argmin([r[0] for r in real])) if real else -1
    log.append(
        {
            "edge": action.edge,
            "route": action.route,
            "transit_steps": action.transit_steps,
            "start": round(start[0], 4),
            "planned_min": round(min(planned), 4) if planned else None,
            "real_min": round(real[i][0], 4) if real else None,
            "real_at": i,
            "geoms": real[i][1:] if real else None,
            "hit": obs.transit_hit_fixed,
            "retimed_min": retimed_min,
        }
    )
    print(len(log) - 1, log[-1], flush=True)
    if obs.transit_hit_fixed:
        print("timestep", m.opt.timestep, "sub", sub, "ctrl step of the hit", i // sub)
        print("tracking error (max |q - q*| rad) every 5 ctrl steps:", [round(t[0], 3) for t in track[:: 5 * sub]])
        print("max speed (rad/s) every 5 ctrl steps:", [round(t[1], 2) for t in track[:: 5 * sub]])
        print(
            "planned q step size (rad) max over joints, around the hit:",
            np.round(np.abs(np.diff(action.q[max(0, i // sub - 8) : i // sub + 8], axis=0)).max(axis=1), 3),
        )
        print("real distances every 5 ctrl steps:", [round(r[0], 4) for r in real[:: 5 * sub]])
        print("planned distances every 5 ctrl steps:", np.round(planned[::5], 4))
        print(
            "qd* max around the hit:", np.round(np.abs(action.qd[max(0, i // sub - 8) : i // sub + 8]).max(axis=1), 2)
        )
    return obs


ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
ap.add_argument("maps", type=Path, help="folder of case2.h5: the map the trial ran on")
ap.add_argument("--log", type=Path, help="JSON written: every transit's figures")
ap.add_argument("--law", choices=("constant", "retimed"), default="constant", help="the transits' time law (above)")
args = ap.parse_args()
executor.SimulatedRealWorld.execute = execute
if args.law == "constant":
    actions.retime = lambda q0, targets, dt: np.asarray(targets, np.float64)  # the ninth session's law
robot = load_robot("panda")
maps = load_maps(robot, ("case2",), args.maps)
cfg = EvalConfig(
    tasks="hard",
    failures=("case2",),
    scenarios=(2,),
    asms=("greedy",),
    trials=15,
    part=(12, 15),
    planner=PlannerConfig(push_weight=1.0),
    backend="cpu",
)
with tempfile.TemporaryDirectory() as out:
    recs = evaluate(robot, maps, cfg, Path(out), progress=False)
rec = json.loads((Path(__file__).parent / "tunnel_push_weight2_h100_2026-11-26" / "cpu_eval_w1.json").read_text())
r = next(x for x in rec if x["seed"] == 2011)
print("same edges as recorded:", [s["edge"] for s in recs[0]["steps"]] == [s["edge"] for s in r["steps"]])
if args.law == "constant":
    pairs = [(x["real_min"], x["retimed_min"]) for x in log if x["retimed_min"] is not None]
    least_c, least_r = min(a for a, _ in pairs), min(b for _, b in pairs)
    print(f"least distance over the trial's transits: constant speed {least_c} m; retimed {least_r} m")
if args.log is not None:
    args.log.write_text(json.dumps(log, indent=1))
