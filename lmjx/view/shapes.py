"""MuJoCo geoms as triangle meshes for the viewer: each geom's mesh in its own frame (a mesh
geom's own triangles, `mesh_vert` and `mesh_face`; capsules, boxes and the other primitives
tessellated, a cylinder with flat caps as C MuJoCo's), its pose in the world from
`mj_kinematics`, which geoms show a body (its mesh geoms where it has any: an MJCF's visual
meshes; else its capsules, boxes and cylinders), and the arm merged into one mesh at a
configuration (the swept arm).  Pure numpy and MuJoCo; nothing here draws."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

CAPSULE_SEGMENTS = 16  # around the axis
CAPSULE_RINGS = 4  # per hemisphere


@dataclass(frozen=True)
class Mesh:
    vertices: np.ndarray  # (V, 3) float32
    faces: np.ndarray  # (F, 3) uint32


def capsule(radius: float, half_length: float, segments: int = CAPSULE_SEGMENTS, rings: int = CAPSULE_RINGS) -> Mesh:
    """A capsule along z: a cylinder of half length `half_length` capped by hemispheres."""
    rows = []  # (z, r) of each ring, from the bottom pole to the top pole
    for k in range(rings + 1):
        a = -np.pi / 2 + np.pi / 2 * k / rings
        rows.append((-half_length + radius * np.sin(a), radius * np.cos(a)))
    for k in range(rings + 1):
        a = np.pi / 2 * k / rings
        rows.append((half_length + radius * np.sin(a), radius * np.cos(a)))
    t = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    verts = np.array([(r * np.cos(u), r * np.sin(u), z) for z, r in rows for u in t], np.float32)
    faces = []
    for i in range(len(rows) - 1):
        for j in range(segments):
            a, b = i * segments + j, i * segments + (j + 1) % segments
            c, d = a + segments, b + segments
            faces += [(a, b, d), (a, d, c)]
    return Mesh(verts, np.array(faces, np.uint32))


def cylinder(radius: float, half_height: float, segments: int = CAPSULE_SEGMENTS) -> Mesh:
    """An upright cylinder along z of `radius` and half height `half_height`, flat caps, centred
    at the origin (its side a prism of `segments` faces whose corners lie on the circle)."""
    t = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([radius * np.cos(t), radius * np.sin(t)], -1)
    verts = np.concatenate([
        np.column_stack([ring, np.full(segments, -half_height)]),
        np.column_stack([ring, np.full(segments, half_height)]),
        [[0.0, 0.0, -half_height], [0.0, 0.0, half_height]],
    ]).astype(np.float32)  # fmt: skip
    bottom, top = 2 * segments, 2 * segments + 1
    faces = []
    for j in range(segments):  # counter-clockwise seen from outside: the normals point out
        a, b = j, (j + 1) % segments
        faces += [(a, b, b + segments), (a, b + segments, a + segments), (bottom, b, a),
                  (top, a + segments, b + segments)]  # fmt: skip
    return Mesh(verts, np.array(faces, np.uint32))


def box(half: np.ndarray) -> Mesh:
    """A box of half sizes `half` (3,), centred at the origin."""
    h = np.asarray(half, np.float32)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float32) * h
    faces = [  # counter-clockwise seen from outside: the normals point out
        (0, 3, 2), (0, 1, 3), (4, 7, 5), (4, 6, 7),  # -x, +x
        (0, 5, 1), (0, 4, 5), (2, 7, 6), (2, 3, 7),  # -y, +y
        (0, 6, 4), (0, 2, 6), (1, 7, 3), (1, 5, 7),  # -z, +z
    ]  # fmt: skip
    return Mesh(corners, np.array(faces, np.uint32))


def mesh_asset(m: mujoco.MjModel, mesh_id: int) -> Mesh:
    """Mesh asset `mesh_id`'s triangles, in the frame MuJoCo compiled it to (a mesh geom's own
    frame: MuJoCo moves the geom's pose to the mesh's centre and axes)."""
    v0, nv = int(m.mesh_vertadr[mesh_id]), int(m.mesh_vertnum[mesh_id])
    f0, nf = int(m.mesh_faceadr[mesh_id]), int(m.mesh_facenum[mesh_id])
    return Mesh(m.mesh_vert[v0 : v0 + nv].astype(np.float32), m.mesh_face[f0 : f0 + nf].astype(np.uint32))


def geom_mesh(m: mujoco.MjModel, g: int) -> Mesh | None:
    """Geom g's mesh in its own frame: a mesh geom's triangles; capsules, boxes, planes (a thin
    box), spheres (round) and cylinders (flat caps: `cylinder`); None for other types (height
    fields, ellipsoids: lmjx's models use none)."""
    t, size = int(m.geom_type[g]), m.geom_size[g]
    if t == mujoco.mjtGeom.mjGEOM_MESH and m.geom_dataid[g] >= 0:
        return mesh_asset(m, int(m.geom_dataid[g]))
    if t == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return capsule(float(size[0]), float(size[1]))
    if t == mujoco.mjtGeom.mjGEOM_BOX:
        return box(size)
    if t == mujoco.mjtGeom.mjGEOM_SPHERE:
        return capsule(float(size[0]), 0.0)
    if t == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return cylinder(float(size[0]), float(size[1]))
    if t == mujoco.mjtGeom.mjGEOM_PLANE:
        return box(np.array([size[0] or 2.0, size[1] or 2.0, 1e-4]))
    return None


def geom_rgb(m: mujoco.MjModel, g: int) -> tuple[int, int, int]:
    """A geom's colour as 0-255 RGB (its material's where it has one)."""
    rgba = m.mat_rgba[m.geom_matid[g]] if m.geom_matid[g] >= 0 else m.geom_rgba[g]
    return tuple(round(255 * float(c)) for c in rgba[:3])  # type: ignore[return-value]


def mat_to_wxyz(xmat: np.ndarray) -> np.ndarray:
    """(..., 9) row-major rotation matrices -> (..., 4) unit quaternions w, x, y, z."""
    flat = np.asarray(xmat, np.float64).reshape(-1, 9)
    out = np.empty((len(flat), 4))
    for i, r in enumerate(flat):
        mujoco.mju_mat2Quat(out[i], r)
    return out.reshape(*np.shape(xmat)[:-1], 4)


def geom_poses(m: mujoco.MjModel, d: mujoco.MjData, geoms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World positions (n, 3) and orientations (n, 4: w, x, y, z) of `geoms` in `d`
    (after `mj_kinematics`)."""
    return d.geom_xpos[geoms].copy(), mat_to_wxyz(d.geom_xmat[geoms])


def shown_geoms(m: mujoco.MjModel, geoms: list[int] | np.ndarray | range) -> np.ndarray:
    """Of `geoms`, the ones drawn: a body's mesh geoms where it has any (an MJCF's visual
    meshes: what the robot looks like), else its capsules, boxes and other primitives (its
    collision geometry); never a geom without a shape to draw."""
    geoms = [int(g) for g in geoms]
    with_mesh = {int(m.geom_bodyid[g]) for g in geoms if int(m.geom_type[g]) == mujoco.mjtGeom.mjGEOM_MESH}
    out = []
    for g in geoms:
        is_mesh = int(m.geom_type[g]) == mujoco.mjtGeom.mjGEOM_MESH
        if is_mesh == (int(m.geom_bodyid[g]) in with_mesh) and geom_mesh(m, g) is not None:
            out.append(g)
    return np.array(out, np.int64)


def arm_geoms(m: mujoco.MjModel, robot_bodies: set[str]) -> np.ndarray:
    """The geoms of the arm (the bodies named `robot_bodies`) drawn (`shown_geoms`)."""
    return shown_geoms(m, [g for g in range(m.ngeom) if m.body(int(m.geom_bodyid[g])).name in robot_bodies])


def concatenate(meshes: list[Mesh]) -> Mesh:
    """The meshes as one (their vertices in one array, the faces renumbered)."""
    if not meshes:
        return Mesh(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32))
    base = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
    return Mesh(
        np.concatenate([m.vertices for m in meshes]).astype(np.float32),
        np.concatenate([m.faces + b for m, b in zip(meshes, base, strict=True)]).astype(np.uint32),
    )


def merged(meshes: list[Mesh], positions: np.ndarray, wxyzs: np.ndarray) -> Mesh:
    """The meshes placed at their poses, as one mesh."""
    placed = []
    for mesh, pos, quat in zip(meshes, positions, wxyzs, strict=True):
        R = np.empty(9)
        mujoco.mju_quat2Mat(R, np.asarray(quat, np.float64))
        placed.append(
            Mesh(mesh.vertices @ R.reshape(3, 3).T.astype(np.float32) + np.asarray(pos, np.float32), mesh.faces)
        )
    return concatenate(placed)


class ArmPoser:
    """The arm's drawn geoms at any configuration: `poses(q)` gives each geom's world pose,
    `mesh(q)` the whole arm as one mesh (coarse capsules: for many poses at once)."""

    def __init__(self, m: mujoco.MjModel, robot_qpos: np.ndarray, geoms: np.ndarray) -> None:
        self.m = m
        self.d = mujoco.MjData(m)
        self.qpos = np.asarray(robot_qpos, np.int64)
        self.geoms = geoms
        self.coarse = [self._coarse(g) for g in geoms]

    def _coarse(self, g: int) -> Mesh:
        size = self.m.geom_size[g]
        if int(self.m.geom_type[g]) == mujoco.mjtGeom.mjGEOM_CAPSULE:
            return capsule(float(size[0]), float(size[1]), segments=10, rings=2)
        mesh = geom_mesh(self.m, g)
        assert mesh is not None
        return mesh

    def poses(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.d.qpos[self.qpos] = q
        mujoco.mj_kinematics(self.m, self.d)
        return geom_poses(self.m, self.d, self.geoms)

    def mesh(self, q: np.ndarray) -> Mesh:
        pos, quat = self.poses(q)
        return merged(self.coarse, pos, quat)

    def site(self, q: np.ndarray, site: int) -> np.ndarray:
        """World position (3,) of site `site` at q."""
        self.d.qpos[self.qpos] = q
        mujoco.mj_kinematics(self.m, self.d)
        return self.d.site_xpos[site].copy()
