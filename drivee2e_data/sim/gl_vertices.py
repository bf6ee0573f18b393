"""The vertices the GL renderer draws: pybullet visual shapes (the signal lamps, and any body
without a model) read as triangles, the twin's meshes, and posed procedural models, each as rows
of `FLOATS_PER_VERTEX` floats in world coordinates (`VERTEX_FORMAT`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.sim.models import Material, ModelMesh
from drivee2e_data.sim.models.mesh import emission, joint_transforms
from drivee2e_data.sim.twin_plan import TwinMesh, box_mesh, prism_mesh, sphere_mesh

CYLINDER_SIDES = 16
# spheres are small here (signal lamps and heads, 12 cm): 80 triangles each, half the twin's
# crowns' (42 lamps are most of what moves or changes colour)
SPHERE_RINGS, SPHERE_SEGMENTS = 5, 10
# position (3), normal (3), colour (3), body id + 1, emission (0..1), material (`Material`)
FLOATS_PER_VERTEX = 12
VERTEX_FORMAT = "3f 3f 3f 1f 1f 1f"
VERTEX_INPUTS = ("in_position", "in_normal", "in_colour", "in_body", "in_emission", "in_material")
POSITION_ONLY = f"3f {4 * (FLOATS_PER_VERTEX - 3)}x"  # the shadow pass reads positions alone


@dataclass(frozen=True)
class _Mesh:
    """Triangles as a vertex soup in a body's frame: `(3T, 3)` positions and normals, and the
    index of the visual shape (its colour) of each vertex."""

    positions: NDArray[np.float32]
    normals: NDArray[np.float32]
    shape: NDArray[np.int32]


def _flat_triangles(
    vertices: NDArray, indices: NDArray, normals: NDArray | None = None
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """An indexed mesh as a vertex soup, with the given per-vertex normals or each triangle's."""
    corners = np.asarray(indices, dtype=np.int64).reshape(-1)
    positions = np.asarray(vertices, dtype=np.float64)[corners]
    if normals is not None:
        return positions.astype(np.float32), np.asarray(normals, np.float64)[corners].astype(
            np.float32
        )
    triangles = positions.reshape(-1, 3, 3)
    face = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    face /= np.maximum(np.linalg.norm(face, axis=1, keepdims=True), 1e-12)
    return positions.astype(np.float32), np.repeat(face, 3, axis=0).astype(np.float32)


def read_obj(path: Path) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """The triangles of an OBJ file as written by `sim.twin` (`v`, optional `vn`, `f` with
    1-based indices, `a` or `a//n`), as a vertex soup with normals."""
    vertices, normals, faces = [], [], []
    for line in path.read_text().splitlines():
        kind, _, rest = line.partition(" ")
        if kind == "v":
            vertices.append(rest.split())
        elif kind == "vn":
            normals.append(rest.split())
        elif kind == "f":
            faces.append([int(token.split("/")[0]) - 1 for token in rest.split()])
    if not faces:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32)
    vertex_array = np.asarray(vertices, dtype=np.float64)
    normal_array = np.asarray(normals, dtype=np.float64) if normals else None
    return _flat_triangles(vertex_array, np.asarray(faces), normal_array)


def primitive_triangles(
    geometry: int, dimensions: Sequence[float], mesh_file: str
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """The triangles of one pybullet visual shape in its own frame (pybullet's geometry codes:
    2 sphere (radius), 3 box (full extents), 4 cylinder (length, radius), 5 mesh (file))."""
    if geometry == 5:
        return read_obj(Path(mesh_file))
    if geometry == 3:
        return _flat_triangles(*box_mesh(np.zeros(3), 0.0, np.asarray(dimensions[:3])))
    if geometry == 2:
        vertices, indices, normals = sphere_mesh(
            np.zeros(3), float(dimensions[0]), rings=SPHERE_RINGS, segments=SPHERE_SEGMENTS
        )
        return _flat_triangles(vertices, indices, normals)
    if geometry == 4:
        length, radius = float(dimensions[0]), float(dimensions[1])
        angles = np.linspace(0.0, 2 * np.pi, CYLINDER_SIDES, endpoint=False)
        circle = radius * np.column_stack([np.cos(angles), np.sin(angles)])
        return _flat_triangles(*prism_mesh(circle, -0.5 * length, 0.5 * length))
    raise ValueError(f"pybullet visual geometry {geometry}: the GL renderer draws 2, 3, 4 and 5")


def quaternion_rotation(quaternion: Sequence[float]) -> NDArray[np.float64]:
    """3x3 rotation of a pybullet quaternion (x, y, z, w)."""
    x, y, z, w = quaternion
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


class _Body:
    """One body's visual shapes in its base frame, and each shape's colour as first read."""

    def __init__(self, p, client: int, body: int) -> None:
        self.body = body
        # each list starts empty-shaped: a body without visual shapes is an empty mesh
        positions, normals = [np.zeros((0, 3))], [np.zeros((0, 3))]
        shapes = [np.zeros(0, np.int32)]
        shape_data = p.getVisualShapeData(body, physicsClientId=client)
        for index, data in enumerate(shape_data):
            local_position, local_orientation = data[5], data[6]
            triangles, triangle_normals = primitive_triangles(data[2], data[3], data[4].decode())
            rotation = quaternion_rotation(local_orientation)
            positions.append(triangles @ rotation.T + np.asarray(local_position))
            normals.append(triangle_normals @ rotation.T)
            shapes.append(np.full(len(triangles), index, np.int32))
        self.mesh = _Mesh(
            np.concatenate(positions).astype(np.float32),
            np.concatenate(normals).astype(np.float32),
            np.concatenate(shapes),
        )
        self.colours = _colours(shape_data)
        self.last: tuple[tuple, NDArray[np.float32]] | None = None  # the last pose's vertices

    def vertices(self, p, client: int, lamp: bool) -> NDArray[np.float32]:
        """`(3T, FLOATS_PER_VERTEX)` the body at its pose now, in world coordinates; a `lamp`
        has its colours read again and shines them unshaded."""
        position, orientation = p.getBasePositionAndOrientation(self.body, physicsClientId=client)
        if lamp:
            self.colours = _colours(p.getVisualShapeData(self.body, physicsClientId=client))
        # a signal's lamps stand still and change colour a few times a clip: their vertices
        # are kept while neither changes (42 lamps had cost 2.8 ms a step on 2 cores)
        key = (position, orientation, lamp, self.colours.tobytes())
        if self.last is not None and self.last[0] == key:
            return self.last[1]
        rotation = quaternion_rotation(orientation)
        out = np.empty((len(self.mesh.positions), FLOATS_PER_VERTEX), np.float32)
        out[:, 0:3] = self.mesh.positions @ rotation.T + np.asarray(position)
        out[:, 3:6] = self.mesh.normals @ rotation.T
        out[:, 6:9] = self.colours[self.mesh.shape] if len(self.colours) else 0.0
        out[:, 9] = self.body + 1
        out[:, 10] = 1.0 if lamp else 0.0
        out[:, 11] = float(Material.LAMP if lamp else Material.MATTE)
        self.last = (key, out)
        return out


def _colours(shape_data) -> NDArray[np.float32]:
    """`(S, 3)` RGB of each visual shape in pybullet's `getVisualShapeData` answer."""
    return np.asarray([data[7][:3] for data in shape_data], dtype=np.float32).reshape(-1, 3)


def static_vertices(meshes: Sequence[TwinMesh]) -> NDArray[np.float32]:
    """`(3T, FLOATS_PER_VERTEX)` the twin's meshes as one vertex soup, in the order given."""
    parts = [np.zeros((0, FLOATS_PER_VERTEX), np.float32)]
    for mesh in meshes:
        positions, normals = _flat_triangles(mesh.vertices, mesh.indices, mesh.normals)
        out = np.empty((len(positions), FLOATS_PER_VERTEX), np.float32)
        out[:, 0:3], out[:, 3:6] = positions, normals
        out[:, 6:9] = mesh.rgba[:3]
        out[:, 9] = mesh.body + 1
        out[:, 10] = 0.0
        out[:, 11] = float(mesh.material)
        parts.append(out)
    return np.concatenate(parts)


def static_anchors(meshes: Sequence[TwinMesh]) -> NDArray[np.float64]:
    """`(T, 2)` where each triangle of `static_vertices(meshes)` belongs on the ground
    (`TwinMesh.anchors_xy`; NaN: its own centroid)."""
    parts = [np.zeros((0, 2))]
    for mesh in meshes:
        triangles = len(np.asarray(mesh.indices).reshape(-1)) // 3
        anchors = (
            mesh.anchors_xy if mesh.anchors_xy is not None else np.full((triangles, 2), np.nan)
        )
        parts.append(np.asarray(anchors, np.float64).reshape(triangles, 2))
    return np.concatenate(parts)


def placed_joints(
    model: ModelMesh, animation, position: Sequence[float], orientation: Sequence[float]
) -> NDArray[np.float64]:
    """`(J, 3, 4)` each joint's transform from the model frame to the world, `[R | t]`: the
    model posed by `animation` (`models.Animation`) at a body's pose (pybullet's position and
    quaternion)."""
    rotation = quaternion_rotation(orientation)
    transforms = joint_transforms(model, animation)  # a rigid model's: the identity
    placed = np.empty_like(transforms)
    placed[:, :, :3] = rotation @ transforms[:, :, :3]
    placed[:, :, 3] = transforms[:, :, 3] @ rotation.T + np.asarray(position, np.float64)
    return placed


class PlacedModel:
    """One body's model, posed and placed each frame in one pass (`models.pose` placed at
    the body's pose, the reference, in about a quarter of its time): its triangles sorted by
    joint once (each triangle hangs from one joint), then each joint's transform composed with
    the body's pose and applied to its block of vertices with one matrix product over positions
    (homogeneous) and normals together; the columns that never change (colour, body id,
    material) kept in a template. The same triangles as the reference, in joint order."""

    def __init__(self, model: ModelMesh, body: int) -> None:
        self.model = model
        joints = np.asarray(model.joints)
        triangle_joints = joints[::3]
        if np.any(joints.reshape(-1, 3) != triangle_joints[:, None]):
            raise ValueError("a model triangle hangs from two joints: it cannot be placed rigidly")
        triangles = np.argsort(triangle_joints, kind="stable")
        self.order = (3 * triangles[:, None] + np.arange(3)).reshape(-1)
        counts = np.bincount(joints, minlength=len(model.joint_table))
        ends = np.cumsum(counts)
        self.blocks = [(joint, int(end - count), int(end))
                       for joint, (count, end) in enumerate(zip(counts, ends, strict=True))
                       if count]  # fmt: skip
        vertices = len(joints)
        # [x, y, z, 1, nx, ny, nz]: one product gives the placed position and normal
        self.local = np.empty((vertices, 7), np.float32)
        self.local[:, 0:3] = model.positions[self.order]
        self.local[:, 3] = 1.0
        self.local[:, 4:7] = model.normals[self.order]
        self.placed = np.empty((vertices, 6), np.float32)
        self.template = np.empty((vertices, FLOATS_PER_VERTEX), np.float32)
        self.template[:, 6:9] = model.colours[self.order]
        self.template[:, 9] = body + 1
        self.template[:, 11] = model.materials[self.order]
        self.emissions: dict[tuple[bool, bool], NDArray[np.float32]] = {}

    def vertices(
        self, animation, position: Sequence[float], orientation: Sequence[float]
    ) -> NDArray[np.float32]:
        """`(N, FLOATS_PER_VERTEX)` the model posed by `animation` (`models.Animation`) at a
        body's pose (pybullet's position and quaternion), in world coordinates."""
        model = self.model
        placed = placed_joints(model, animation, position, orientation)
        linear, offset = placed[:, :, :3], placed[:, :, 3]
        # per joint the (7, 6) matrix taking [p, 1, n] to [R p + t, R n]
        products = np.zeros((len(linear), 7, 6), np.float32)
        products[:, 0:3, 0:3] = linear.transpose(0, 2, 1)
        products[:, 3, 0:3] = offset
        products[:, 4:7, 3:6] = linear.transpose(0, 2, 1)
        for joint, start, end in self.blocks:
            np.matmul(self.local[start:end], products[joint], out=self.placed[start:end])
        out = self.template.copy()
        out[:, 0:6] = self.placed
        lights = (bool(animation.headlights), bool(animation.brake))
        if lights not in self.emissions:
            self.emissions[lights] = emission(model, animation)[self.order]
        out[:, 10] = self.emissions[lights]
        return out
