"""Static description of an arm, as the kernels consume it.

Everything here is numpy: topology, ids, offsets and limits are resolved once when a kernel
is traced and become constants of the compiled program.  `lmjx.robot` builds an `ArmModel`
from the MJCF; the kernels never parse files.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Tree(NamedTuple):
    """A kinematic tree of rigid bodies, each moved by at most one hinge joint.

    Bodies are listed parents first.  Frames follow MuJoCo: `pos`/`rot` place a body in its
    parent's frame; a hinge rotates the body about `axis` through `anchor` (body frame).
    """

    parent: np.ndarray  # (nb,) int, index of the parent body, -1 for the world
    joint: np.ndarray  # (nb,) int, index of the joint moving the body, -1 if welded
    pos: np.ndarray  # (nb, 3) body origin in the parent frame
    rot: np.ndarray  # (nb, 3, 3) body orientation in the parent frame
    axis: np.ndarray  # (nj, 3) joint axis in its body's frame (unit)
    anchor: np.ndarray  # (nj, 3) joint anchor in its body's frame
    joint_body: np.ndarray  # (nj,) int, the body each joint moves
    ancestors: np.ndarray  # (nb, nj) float 0/1: joint j moves body b


class ArmModel(NamedTuple):
    """What the IK, collision and reach kernels need to know about the robot and table."""

    tree: Tree
    lower: np.ndarray  # (nj,) joint position lower limits [rad]
    upper: np.ndarray  # (nj,) joint position upper limits [rad]
    site_body: np.ndarray  # (ns,) int, body of each site
    site_pos: np.ndarray  # (ns, 3) site position in its body frame
    site_radius: np.ndarray  # (ns,) local radius of the link around the site [m]
    tool_body: int  # body whose z axis is the tool (approach) axis
    cap_body: np.ndarray  # (nc,) int, body of each collision capsule
    cap_a: np.ndarray  # (nc, 3) capsule segment start, body frame
    cap_b: np.ndarray  # (nc, 3) capsule segment end, body frame
    cap_r: np.ndarray  # (nc,) capsule radius
    self_pairs: np.ndarray  # (np, 2) int, capsule pairs checked for self collision
    table_caps: np.ndarray  # (nt,) int, capsules checked against the table
    table_z: float  # height of the table top in the world frame
    table_center: np.ndarray  # (3,) table box centre, world frame
    table_rot: np.ndarray  # (3, 3) table box orientation, world frame
    table_half: np.ndarray  # (3,) table box half sizes
