"""Locked-joint failures: a robot's named presets and the 'J2=0.3,J4=-1.5' syntax.

A `Failure` says which joints of an nq-joint arm are locked and at which angles.
Everything downstream (IK, Jacobians, dynamics) treats locked joints as constants and works
over `free` only.  The presets of each robot (the Panda's case1 and case2, the UR5e's
case1 and case2 of its own) live with the robot (`robot.PROFILES`); docs/DETAILS.md and docs/ROBOTS.md
explain how each was chosen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lmjx.errors import FailureSpecError
from lmjx.model.robot import Robot, as_robot


@dataclass(frozen=True)
class Failure:
    """A set of locked joints (1-based joint numbers) of an nq-joint arm and their angles in radians."""

    name: str
    locked: tuple[tuple[int, float], ...]  # ((joint number 1..nq, angle), ...) sorted
    nq: int

    @property
    def locked_joints(self) -> tuple[int, ...]:
        return tuple(j for j, _ in self.locked)

    def free(self, nq: int | None = None) -> tuple[int, ...]:
        """0-based indices of the joints that still move."""
        locked = set(self.locked_joints)
        return tuple(i for i in range(nq or self.nq) if i + 1 not in locked)

    def q_fixed(self, nq: int | None = None) -> np.ndarray:
        """(nq,) joint vector holding the locked angles (zeros at free joints)."""
        q = np.zeros(nq or self.nq)
        for j, a in self.locked:
            q[j - 1] = a
        return q

    @property
    def spec(self) -> str:
        """Canonical spec string: the preset name (or 'none') or 'J6=1.5,J7=-0.3'."""
        if self.name and "=" not in self.name:
            return self.name
        return ",".join(f"J{j}={a:g}" for j, a in self.locked)

    def __repr__(self) -> str:
        locks = ", ".join(f"J{j}={a:.4g}" for j, a in self.locked) or "no locked joints"
        return f"Failure({self.spec!r}: {locks}; {self.nq - len(self.locked)} of {self.nq} joints free)"

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


def _names(robot: Robot) -> str:
    return ", ".join(["none", *robot.profile.presets])


def as_failure(failure: Failure | str, robot: Robot) -> Failure:
    """The failure an argument names: a spec string (see `parse_failure`) or a `Failure`,
    checked against `robot` (its joint count and limits)."""
    if isinstance(failure, Failure):
        if failure.nq != robot.nq:
            raise FailureSpecError(
                f"failure {failure.spec}: made for an arm of {failure.nq} joints, {robot.key} has {robot.nq}"
            )
        for j, a in failure.locked:
            _check_angle(robot, j, a, failure.spec)
        return failure
    if not isinstance(failure, str):
        raise FailureSpecError(f"a failure is a spec such as 'case2' or 'J2=0.3,J4=-1.5' or a Failure, not {failure!r}")
    return parse_failure(failure, robot)


def parse_failure(spec: str, robot: Robot | str | None = None) -> Failure:
    """Parse 'none', one of the robot's presets, or a comma list 'J2=0.3,J4=-1.5' (radians).
    `robot`: a Robot, a shipped robot's name or an MJCF's path (default: the Panda).

    >>> import lmjx
    >>> lmjx.parse_failure("case2")
    Failure('case2': J6=0.935, J7=-0.7193; 5 of 7 joints free)
    >>> lmjx.parse_failure("J2=0.3,J4=-1.5", "ur5e")
    Failure('J2=0.3,J4=-1.5': J2=0.3, J4=-1.5; 4 of 6 joints free)
    """
    robot = as_robot(robot)
    text = spec.strip()
    example = "'J2=0.3,J4=-1.5'"
    if not text:
        raise FailureSpecError(f"empty failure spec; use {_names(robot)} or e.g. {example}")
    key = text.lower()
    presets = {"none": {}, **robot.profile.presets}
    if key in presets:
        locked = tuple(sorted(presets[key].items()))
        for j, a in locked:
            _check_angle(robot, j, a, text)
        return Failure(key, locked, robot.nq)
    nq = robot.nq
    angles: dict[int, float] = {}
    for part in text.split(","):
        part = part.strip()
        name, sep, value = part.partition("=")
        name = name.strip().upper()
        if not sep or not name.startswith("J") or not name[1:].isdigit():
            raise FailureSpecError(
                f"failure '{spec}': cannot read '{part}'; use {_names(robot)} (the presets of {robot.key}) or e.g. "
                f"{example}"
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
    return Failure(",".join(f"J{j}={a:g}" for j, a in locked), locked, nq)
