"""The edge rollout of `kernels/rollout.py`, written again serially on C MuJoCo.

Independent of lmjx's kernels: Jacobians from mj_jacSite, Jdot from mj_jacDot, torques from
mj_rne (the inverse dynamics of mj_inverse without contact forces; tests check mj_inverse
itself on contact-free states), collisions from MuJoCo's own contact detection, all in
float64.  Used as the
reference in tests and as the serial baseline in `lmjx bench`.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from kernels.rollout import REASONS, Limits, RolloutSettings
from lmjx.model.failure import Failure
from lmjx.model.robot import Robot


@dataclass
class ReferenceEdge:
    q: np.ndarray  # (n, nq) states 0 .. last evaluated
    qd: np.ndarray  # (n, nq)
    qdd: np.ndarray  # (n, nq)
    tau: np.ndarray  # (n, nq) motor torques incl. friction
    p: np.ndarray  # (n, 3) point positions
    manipulability: np.ndarray  # (n,)
    valid: bool
    fail_step: int
    reason: str


def gaz_friction(phi: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """Gaz et al. joint friction; phi is (3, nj)."""
    p1, p2, p3 = phi
    return p1 / (1 + np.exp(-p2 * (qd + p3))) - p1 / (1 + np.exp(-p2 * p3))


class ReferenceRollout:
    """Serial C MuJoCo rollouts for one failure and one point (site)."""

    def __init__(self, robot: Robot, failure: Failure, settings: RolloutSettings, limits: Limits | None = None) -> None:
        self.robot = robot
        self.limits = limits or Limits(robot.qd_max, robot.qdd_max, robot.tau_max, robot.friction)
        self.m = robot.mj
        self.d = mujoco.MjData(self.m)
        self.free = np.array(failure.free(robot.nq))
        self.q_fixed = failure.q_fixed(robot.nq)
        self.settings = settings

    def _jacobian(self, site: int) -> np.ndarray:
        jp = np.zeros((3, self.m.nv))
        jr = np.zeros((3, self.m.nv))
        mujoco.mj_jacSite(self.m, self.d, jp, jr, site)
        return np.vstack([jp, jr])[:, self.free]

    def _lstsq(self, jac: np.ndarray, b: np.ndarray) -> np.ndarray:
        nf = jac.shape[1]
        lam = self.settings.damping
        if nf >= 6:
            return jac.T @ np.linalg.solve(jac @ jac.T + lam * np.eye(6), b)
        return np.linalg.solve(jac.T @ jac + lam * np.eye(nf), jac.T @ b)

    def run(self, site: int, q0_free: np.ndarray, twist: np.ndarray, length: int) -> ReferenceEdge:
        m, d, free, s = self.m, self.d, self.free, self.settings
        r = self.robot
        q = self.q_fixed.copy()
        q[free] = q0_free
        rows: dict[str, list] = {k: [] for k in ("q", "qd", "qdd", "tau", "p", "m")}
        fail_step, reason = -1, "ok"
        for k in range(length + 1):
            d.qpos[:] = q
            d.qvel[:] = 0
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            jac = self._jacobian(site)
            qd = np.zeros(m.nv)
            qd[free] = self._lstsq(jac, twist)
            d.qvel[:] = qd
            mujoco.mj_comVel(m, d)
            jp_dot = np.zeros((3, m.nv))
            jr_dot = np.zeros((3, m.nv))
            mujoco.mj_jacDot(m, d, jp_dot, jr_dot, d.site_xpos[site], m.site_bodyid[site])
            bias = np.concatenate([jp_dot @ qd, jr_dot @ qd])
            qdd = np.zeros(m.nv)
            qdd[free] = self._lstsq(jac, -bias)
            d.qacc[:] = qdd
            rne = np.zeros(m.nv)
            mujoco.mj_rne(m, d, 1, rne)  # M qdd + C qd + g: mj_inverse without contact forces
            tau = rne + gaz_friction(self.limits.friction, qd)
            mujoco.mj_forward(m, d)  # contacts at this configuration (velocities do not matter)
            jj = jac @ jac.T if len(free) >= 6 else jac.T @ jac
            manip = float(np.sqrt(max(np.linalg.det(jj), 0.0)))
            fails = [
                bool(np.any(q[free] < r.lower[free] - 1e-6) or np.any(q[free] > r.upper[free] + 1e-6)),
                bool(np.any(np.abs(qd[free]) > self.limits.qd_max[free])),
                bool(np.any(np.abs(qdd[free]) > self.limits.qdd_max[free])),
                bool(np.any(np.abs(tau[free]) > self.limits.tau_max[free])),
                any(m.geom_bodyid[c.geom1] != 0 and m.geom_bodyid[c.geom2] != 0 for c in d.contact[: d.ncon]),
                any(m.geom_bodyid[c.geom1] == 0 or m.geom_bodyid[c.geom2] == 0 for c in d.contact[: d.ncon]),
            ]
            for key, val in zip(
                ("q", "qd", "qdd", "tau", "p", "m"),
                (q.copy(), qd, qdd, tau, d.site_xpos[site].copy(), manip),
                strict=True,
            ):
                rows[key].append(val)
            if any(fails):
                fail_step, reason = k, REASONS[1 + fails.index(True)]
                break
            q = q.copy()
            q[free] += qd[free] * s.dt
        return ReferenceEdge(
            q=np.array(rows["q"]),
            qd=np.array(rows["qd"]),
            qdd=np.array(rows["qdd"]),
            tau=np.array(rows["tau"]),
            p=np.array(rows["p"]),
            manipulability=np.array(rows["m"]),
            valid=fail_step < 0,
            fail_step=fail_step,
            reason=reason,
        )
