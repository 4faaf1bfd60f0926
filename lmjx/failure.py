"""Locked-joint failures: the named cases and the 'J2=0.3,J4=-1.5' syntax.

A `Failure` says which joints are locked and at which angles.  Everything downstream
(IK, Jacobians, dynamics) treats locked joints as constants and works over `free` only.
The lock angles of the named cases live here and nowhere else; README.md explains them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import FailureSpecError
from .robot import Robot

# The paper gives no lock angles; these are lmjx's choices, from full Reach-Ability maps
# over grids of lock angles (README.md, "Failure cases", has the searches and the reasons):
# case1: J7 at its ready-pose angle; (J3, J5) from a 7 x 7 grid
#        (`lmjx lock-search --joints J3,J5 --base J7=0.785398 --grid 7`): the lock whose PM and
#        NPM+PM areas, relative to no failure, are closest to the paper's case 1 (0.62/0.85
#        and 0.85/0.92): grasping limited to part of the table, pushing almost everywhere.
# case2: (J6, J7) from a 9 x 9 grid (`lmjx lock-search --joints J6,J7 --grid 9`): the lock
#        with the smallest PM area (0: the gripper cannot grasp anywhere), ties broken by the
#        largest NPM+PM area; a finer search around it keeps PM at 0 within +-0.1 rad.
PRESETS: dict[str, dict[int, float]] = {
    "none": {},
    "case1": {3: 2.8773, 5: 0.0, 7: math.pi / 4},
    "case2": {6: 0.935, 7: -0.7193},
}


@dataclass(frozen=True)
class Failure:
    """A set of locked joints (1-based joint numbers) and their angles in radians."""

    name: str
    locked: tuple[tuple[int, float], ...]  # ((joint number 1..7, angle), ...) sorted

    @property
    def locked_joints(self) -> tuple[int, ...]:
        return tuple(j for j, _ in self.locked)

    def free(self, nq: int = 7) -> tuple[int, ...]:
        """0-based indices of the joints that still move."""
        locked = set(self.locked_joints)
        return tuple(i for i in range(nq) if i + 1 not in locked)

    def q_fixed(self, nq: int = 7) -> np.ndarray:
        """(nq,) joint vector holding the locked angles (zeros at free joints)."""
        q = np.zeros(nq)
        for j, a in self.locked:
            q[j - 1] = a
        return q

    @property
    def spec(self) -> str:
        """Canonical spec string: the preset name or 'J6=1.5,J7=-0.3'."""
        if self.name in PRESETS:
            return self.name
        return ",".join(f"J{j}={a:g}" for j, a in self.locked)

    def describe(self) -> str:
        if not self.locked:
            return f"{self.name} (no locked joints)"
        locks = ", ".join(f"J{j}={a:.4g}" for j, a in self.locked)
        return f"{self.name} ({locks})"


def _check_angle(robot: Robot, joint: int, angle: float, spec: str) -> None:
    lo, hi = robot.lower[joint - 1], robot.upper[joint - 1]
    if not math.isfinite(angle) or not lo <= angle <= hi:
        raise FailureSpecError(
            f"failure '{spec}': J{joint}={angle:g} rad is outside the joint's limits [{lo:.4f}, {hi:.4f}]"
        )


def parse_failure(spec: str, robot: Robot) -> Failure:
    """Parse 'none', 'case1', 'case2' or a comma list 'J2=0.3,J4=-1.5' (radians)."""
    text = spec.strip()
    if not text:
        raise FailureSpecError("empty failure spec; use none, case1, case2 or e.g. 'J2=0.3,J4=-1.5'")
    key = text.lower()
    if key in PRESETS:
        locked = tuple(sorted(PRESETS[key].items()))
        for j, a in locked:
            _check_angle(robot, j, a, text)
        return Failure(key, locked)
    nq = robot.nq
    angles: dict[int, float] = {}
    for part in text.split(","):
        part = part.strip()
        name, sep, value = part.partition("=")
        name = name.strip().upper()
        if not sep or not name.startswith("J") or not name[1:].isdigit():
            raise FailureSpecError(
                f"failure '{spec}': cannot read '{part}'; use none, case1, case2 or e.g. 'J2=0.3,J4=-1.5'"
            )
        joint = int(name[1:])
        if not 1 <= joint <= nq:
            raise FailureSpecError(f"failure '{spec}': {name} does not exist; joints are J1..J{nq}")
        if joint in angles:
            raise FailureSpecError(f"failure '{spec}': {name} is given twice")
        try:
            angle = float(value)
        except ValueError:
            raise FailureSpecError(f"failure '{spec}': '{value.strip()}' is not an angle in radians") from None
        _check_angle(robot, joint, angle, spec)
        angles[joint] = angle
    if len(angles) >= nq:
        raise FailureSpecError(f"failure '{spec}': locks every joint; at least one must stay free")
    locked = tuple(sorted(angles.items()))
    return Failure(",".join(f"J{j}={a:g}" for j, a in locked), locked)
