"""Meshes of procedural models as plain arrays, the primitives they are built from, and posing.

A `ModelMesh` is a triangle soup in the model's frame (x forward, y left, z up, origin at the
box centre): three vertices a triangle, each with a normal, an RGB colour, a material
(`Material`), a light (`Light`: which of the model's lamps it belongs to, if any) and a joint
(the rigid part it moves with). `pose` moves the joints (wheels that spin and steer, limbs that
swing) and returns the vertices of one instant; the renderer only uploads them.
"""

from __future__ import annotations

import enum
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

CREASE_COS = float(np.cos(np.radians(35.0)))  # faces meeting at less than this angle shade smooth


class Material(enum.IntEnum):
    """How a surface is shaded (the fragment shader's `material`; the codes are part of the
    shader's contract)."""

    MATTE = 0
    PAINT = 1  # car paint: a sun highlight
    GLASS = 2  # dark, a sharp sky and sun reflection
    LAMP = 3  # emissive where lit (the vertex's emission), else matte
    ASPHALT = 4  # grain, patches, wheel tracks (world-space noise)
    PAVEMENT = 5  # paving slabs
    GRASS = 6  # mottled
    FACADE = 7  # storeys and a window grid
    FOLIAGE = 8  # leaf clusters
    MARKING = 9  # road paint: worn
    TYRE = 10  # black rubber
    STREET_LAMP = 11  # a street lamp's face: shines when the street lamps are on
    WINDOW = 12  # a building's window: dark glass, the sky and sun reflected
    WINDOW_LIT = 13  # the same by day; at night it shines its vertex colour (a lit room)
    FOLIAGE_FAR = 14  # leaves as FOLIAGE, on a coarser crown drawn far from the camera


class Light(enum.IntEnum):
    """The lamp a vertex belongs to (0: none); `pose` gives each its emission."""

    NONE = 0
    HEAD = 1
    TAIL = 2  # tail and brake light in one unit: dim with the headlights, bright when braking


@dataclass(frozen=True)
class Joint:
    """A rigid part's pivot in the model frame and how it moves."""

    pivot_m: tuple[float, float, float]
    kind: str  # root, wheel, steer_wheel, hip, knee, ankle, shoulder, elbow, pedal
    side: int = 0  # +1 left, -1 right (limbs swing in opposite phase), 0 none
    parent: int = 0  # joint index this one hangs from (0: the root)


@dataclass(frozen=True)
class ModelMesh:
    """A triangle soup: `(N, 3)` positions and normals (model frame, metres), `(N, 3)` colours
    in [0, 1], `(N,)` materials, lights and joints; N is a multiple of 3."""

    positions: NDArray[np.float32]
    normals: NDArray[np.float32]
    colours: NDArray[np.float32]
    materials: NDArray[np.uint8]
    lights: NDArray[np.uint8]
    joints: NDArray[np.int16]
    joint_table: tuple[Joint, ...] = (Joint((0.0, 0.0, 0.0), "root"),)
    wheel_radius_m: float = 0.0  # 0 for models without wheels
    stride_m: float = 0.0  # a full walk cycle's length (two steps); 0 for models that don't walk

    @property
    def extent_min_m(self) -> NDArray[np.float64]:
        return self.positions.min(axis=0).astype(np.float64)

    @property
    def extent_max_m(self) -> NDArray[np.float64]:
        return self.positions.max(axis=0).astype(np.float64)


@dataclass
class MeshBuilder:
    """Collects triangles part by part; `build` returns the `ModelMesh`."""

    positions: list[NDArray[np.float64]]
    colours: list[NDArray[np.float64]]
    materials: list[NDArray[np.uint8]]
    lights: list[NDArray[np.uint8]]
    joints: list[NDArray[np.int16]]
    smooth: list[NDArray[np.bool_]]
    joint_table: list[Joint]

    def __init__(self) -> None:
        self.positions, self.colours, self.materials = [], [], []
        self.lights, self.joints, self.smooth = [], [], []
        self.joint_table = [Joint((0.0, 0.0, 0.0), "root")]

    def joint(self, joint: Joint) -> int:
        self.joint_table.append(joint)
        return len(self.joint_table) - 1

    def add(
        self,
        triangles: NDArray[np.float64],
        rgb: tuple[float, float, float] | NDArray[np.float64],
        material: Material = Material.MATTE,
        light: Light = Light.NONE,
        joint: int = 0,
        smooth: bool = True,
    ) -> None:
        """Triangles `(T, 3, 3)` (counter-clockwise seen from outside) in one colour (or one per
        triangle, `(T, 3)`) and material."""
        triangles = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
        count = len(triangles)
        if count == 0:
            return
        colour = np.asarray(rgb, dtype=np.float64)
        colour = np.repeat(np.broadcast_to(colour, (count, 3)), 3, axis=0)
        self.positions.append(triangles.reshape(-1, 3))
        self.colours.append(colour)
        self.materials.append(np.full(3 * count, int(material), np.uint8))
        self.lights.append(np.full(3 * count, int(light), np.uint8))
        self.joints.append(np.full(3 * count, joint, np.int16))
        self.smooth.append(np.full(3 * count, smooth))

    def build(self, wheel_radius_m: float = 0.0, stride_m: float = 0.0) -> ModelMesh:
        positions = np.concatenate(self.positions)
        keep = _non_degenerate(positions)
        positions = positions[keep]
        normals = shade_normals(
            positions, np.concatenate(self.joints)[keep], np.concatenate(self.smooth)[keep]
        )
        return ModelMesh(
            positions.astype(np.float32),
            normals.astype(np.float32),
            np.concatenate(self.colours)[keep].astype(np.float32),
            np.concatenate(self.materials)[keep],
            np.concatenate(self.lights)[keep],
            np.concatenate(self.joints)[keep],
            tuple(self.joint_table),
            wheel_radius_m,
            stride_m,
        )


def _non_degenerate(positions: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Per vertex: whether its triangle has an area (lofts collapse where a section has no
    cabin)."""
    triangles = positions.reshape(-1, 3, 3)
    area = np.linalg.norm(
        np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1
    )
    return np.repeat(area > 1e-8, 3)


def face_normals(positions: NDArray[np.float64]) -> NDArray[np.float64]:
    """`(T, 3)` unit normals of a soup's triangles."""
    triangles = positions.reshape(-1, 3, 3)
    normal = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    return normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)


def shade_normals(
    positions: NDArray[np.float64], joints: NDArray[np.int16], smooth: NDArray[np.bool_]
) -> NDArray[np.float64]:
    """Per-vertex normals: where `smooth`, the area-weighted mean of the faces that share the
    vertex's position (and joint), unless a face turns more than the crease angle from it;
    elsewhere each face's own."""
    faces = np.repeat(face_normals(positions), 3, axis=0)
    group = _same_vertex_groups(np.round(positions * 2000).astype(np.int64), joints)
    sums = np.zeros((group.max() + 1, 3))
    np.add.at(sums, group[smooth], faces[smooth])
    mean = sums[group] / np.maximum(np.linalg.norm(sums[group], axis=1, keepdims=True), 1e-12)
    use_mean = smooth & (np.einsum("ij,ij->i", mean, faces) > CREASE_COS)
    return np.where(use_mean[:, None], mean, faces)


def _same_vertex_groups(cells: NDArray[np.int64], joints: NDArray[np.int16]) -> NDArray[np.int64]:
    """`(V,)` a number per vertex shared by the vertices of equal `cells` `(V, 3)` and joint.
    Packed into one unsigned 64-bit key where every cell fits 16 bits (models within 16 m of
    their centre at 0.5 mm cells), as a row-wise `np.unique` sorts ten times slower."""
    if len(cells) and np.abs(cells).max() < 2**15 and joints.min() >= 0 and joints.max() < 2**16:
        packed = (cells + 2**15).astype(np.uint64)
        key = (
            packed[:, 0] << 48 | packed[:, 1] << 32 | packed[:, 2] << 16 | joints.astype(np.uint64)
        )
        return np.unique(key, return_inverse=True)[1].reshape(-1)
    rows = np.column_stack([cells, joints])
    return np.unique(rows, axis=0, return_inverse=True)[1].reshape(-1)


def quads(a: NDArray, b: NDArray, c: NDArray, d: NDArray) -> NDArray[np.float64]:
    """Triangles `(2Q, 3, 3)` of quads with corners a, b, c, d `(Q, 3)` counter-clockwise."""
    first = np.stack([a, b, c], axis=1)
    second = np.stack([a, c, d], axis=1)
    return np.stack([first, second], axis=1).reshape(-1, 3, 3)


def box_mesh(
    centre: NDArray, yaw_rad: float, size_m: NDArray
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The 8 corners and 12 outward triangles of a box of `size_m` (length, width, height)
    centred at `centre` (x, y, z), turned `yaw_rad` about z."""
    # corner k sits at +x when bit 0 is set, +y for bit 1, +z for bit 2
    signs = np.array(
        [[(k & 1) * 2 - 1, (k >> 1 & 1) * 2 - 1, (k >> 2 & 1) * 2 - 1] for k in range(8)]
    )
    local = 0.5 * signs * np.asarray(size_m, dtype=np.float64)
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    faces = [0, 2, 3, 0, 3, 1, 4, 5, 7, 4, 7, 6, 1, 3, 7, 1, 7, 5,
             0, 4, 6, 0, 6, 2, 2, 6, 7, 2, 7, 3, 0, 1, 5, 0, 5, 4]  # fmt: skip
    return local @ rotation.T + np.asarray(centre, dtype=np.float64), np.asarray(faces)


def box(
    centre: tuple[float, float, float] | NDArray, size: tuple[float, float, float] | NDArray
) -> NDArray[np.float64]:
    """Triangles `(12, 3, 3)` of an axis-aligned box (`box_mesh`'s, as a soup)."""
    vertices, indices = box_mesh(np.asarray(centre, dtype=np.float64), 0.0, size)
    return vertices[indices].reshape(-1, 3, 3)


def _rings3(sections_x: NDArray[np.float64], rings: NDArray[np.float64]) -> NDArray[np.float64]:
    points = rings.shape[1]
    x = np.repeat(np.asarray(sections_x, dtype=np.float64)[:, None, None], points, axis=1)
    return np.concatenate([x, rings], axis=2)


def loft(sections_x: NDArray[np.float64], rings: NDArray[np.float64]) -> NDArray[np.float64]:
    """Triangles `(S-1, P, 2, 3, 3)` of the surface through closed rings `(S, P, 2)` of (y, z)
    points placed at increasing `sections_x` `(S,)`, each ring counter-clockwise in the (y, z)
    plane: quad (k, j) joins points j and j+1 of rings k and k+1."""
    ring3 = _rings3(sections_x, rings)
    count, points = rings.shape[:2]
    following = np.roll(ring3, -1, axis=1)
    a, b = ring3[:-1], following[:-1]
    c, d = following[1:], ring3[1:]
    sides = quads(a.reshape(-1, 3), b.reshape(-1, 3), c.reshape(-1, 3), d.reshape(-1, 3))
    return sides.reshape(count - 1, points, 2, 3, 3)


def loft_caps(sections_x: NDArray[np.float64], rings: NDArray[np.float64]) -> NDArray[np.float64]:
    """Triangles closing a `loft`'s first and last rings (fans from their centroids)."""
    ring3 = _rings3(sections_x, rings)
    return np.concatenate([_fan(ring3[0], reverse=True), _fan(ring3[-1], reverse=False)])


def _fan(ring: NDArray[np.float64], reverse: bool) -> NDArray[np.float64]:
    """A flat cap over a convex-ish ring, from its centroid."""
    centre = np.broadcast_to(ring.mean(axis=0), ring.shape)
    following = np.roll(ring, -1, axis=0)
    triangles = np.stack([centre, ring, following], axis=1)
    return triangles[:, ::-1] if reverse else triangles


def cylinder(
    centre: NDArray | tuple, radius_m: float, length_m: float, axis: int, sides: int = 14
) -> NDArray[np.float64]:
    """Triangles of a closed cylinder along model axis `axis` (0 x, 1 y, 2 z)."""
    angles = np.linspace(0.0, 2 * np.pi, sides, endpoint=False)
    circle = np.column_stack([np.cos(angles), np.sin(angles)]) * radius_m
    half = 0.5 * length_m
    low = np.column_stack([circle, np.full(sides, -half)])
    high = np.column_stack([circle, np.full(sides, half)])
    low_next, high_next = np.roll(low, -1, axis=0), np.roll(high, -1, axis=0)
    wall = quads(low, low_next, high_next, high)
    top = np.stack([np.broadcast_to([0, 0, half], high.shape), high, high_next], axis=1)
    bottom = np.stack([np.broadcast_to([0, 0, -half], low.shape), low_next, low], axis=1)
    triangles = np.concatenate([wall, top, bottom])
    order = {2: [0, 1, 2], 0: [2, 0, 1], 1: [1, 2, 0]}[axis]  # the local z becomes `axis`
    # a cyclic permutation of the axes keeps the winding (a swap would mirror it)
    return triangles[..., order] + np.asarray(centre, dtype=np.float64)


def ellipsoid(
    centre: NDArray | tuple, radii_m: tuple[float, float, float], rings: int = 6, segments: int = 8
) -> NDArray[np.float64]:
    """Triangles of an ellipsoid (a low-poly UV sphere scaled per axis)."""
    polar = np.linspace(0.0, np.pi, rings + 1)
    azimuth = np.linspace(0.0, 2 * np.pi, segments + 1)
    p, a = np.meshgrid(polar, azimuth, indexing="ij")
    grid = np.stack([np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)], axis=-1)
    grid = grid * np.asarray(radii_m) + np.asarray(centre, dtype=np.float64)
    upper, lower = grid[:-1], grid[1:]
    triangles = quads(
        upper[:, :-1].reshape(-1, 3),
        lower[:, :-1].reshape(-1, 3),
        lower[:, 1:].reshape(-1, 3),
        upper[:, 1:].reshape(-1, 3),
    )
    return triangles


def rotation_y(angle_rad: NDArray[np.float64]) -> NDArray[np.float64]:
    """`(..., 3, 3)` rotations about the model's y axis (pitch: positive turns +x towards -z)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    # filled in place: stacking nine (...) arrays cost 65 us for one angle (posing a frame's
    # agents calls this a hundred times)
    rotations = np.zeros((*np.shape(c), 3, 3))
    rotations[..., 0, 0] = c
    rotations[..., 0, 2] = s
    rotations[..., 1, 1] = 1.0
    rotations[..., 2, 0] = -s
    rotations[..., 2, 2] = c
    return rotations


def rotation_z(angle_rad: NDArray[np.float64]) -> NDArray[np.float64]:
    """`(..., 3, 3)` rotations about the model's z axis (yaw, counter-clockwise from above)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    rotations = np.zeros((*np.shape(c), 3, 3))
    rotations[..., 0, 0] = c
    rotations[..., 0, 1] = -s
    rotations[..., 1, 0] = s
    rotations[..., 1, 1] = c
    rotations[..., 2, 2] = 1.0
    return rotations


@dataclass(frozen=True)
class Animation:
    """One instant of a model's motion, from its track (`sim.animation`)."""

    wheel_angle_rad: float = 0.0  # distance driven / wheel radius
    steer_rad: float = 0.0  # front wheels' angle, left positive
    walk_phase_rad: float = 0.0  # 2 pi per stride (distance walked / stride length)
    walk_amount: float = 0.0  # 0 standing, 1 walking at full swing
    brake: bool = False
    headlights: bool = False


# walk cycle amplitudes (radians): hips swing +-12 degrees (gait studies give 20-25 at a brisk
# pace; less keeps the feet inside the 0.6 m pedestrian box), knees bend up to 22 in the swing
# phase, feet stay level, arms swing opposite the legs by about 15
HIP_SWING_RAD = np.radians(12.0)
KNEE_BEND_RAD = np.radians(22.0)
ARM_SWING_RAD = np.radians(15.0)
ELBOW_BEND_RAD = np.radians(12.0)
PEDAL_SWING_RAD = np.radians(18.0)
TAIL_GLOW = 0.45  # tail lights' emission with the headlights on and no brake
STEER_LIMIT_RAD = np.radians(12.0)  # wheels are drawn turned at most this far (a tyre then pokes
# at most 2 cm out of the box; real arches hide more)


def joint_angles(mesh: ModelMesh, animation: Animation) -> tuple[list[float], list[float]]:
    """Each joint's pitch (about its y axis) and yaw (about its z axis, steering wheels only),
    radians: the joint's rotation is yaw after pitch (`rotation_z(yaw) @ rotation_y(pitch)`).
    Plain floats: a model has a handful of joints and a frame poses dozens of models."""
    phase, amount = animation.walk_phase_rad, animation.walk_amount
    pitch, yaw = [0.0] * len(mesh.joint_table), [0.0] * len(mesh.joint_table)
    for index, joint in enumerate(mesh.joint_table):
        if joint.kind == "wheel":
            pitch[index] = animation.wheel_angle_rad
        elif joint.kind == "steer_wheel":
            pitch[index] = animation.wheel_angle_rad
            yaw[index] = min(max(animation.steer_rad, -STEER_LIMIT_RAD), STEER_LIMIT_RAD)
        elif joint.kind in ("hip", "knee", "ankle"):
            hip, knee = _leg_angles(joint.side, phase, amount)
            pitch[index] = {"hip": hip, "knee": knee, "ankle": -(hip + knee)}[joint.kind]
        elif joint.kind == "shoulder":
            pitch[index] = -joint.side * amount * ARM_SWING_RAD * math.sin(phase)
        elif joint.kind == "elbow":
            pitch[index] = -ELBOW_BEND_RAD * (0.5 + 0.5 * amount)
        elif joint.kind == "pedal":
            pitch[index] = joint.side * PEDAL_SWING_RAD * math.sin(animation.wheel_angle_rad)
    return pitch, yaw


JOINT_KINDS = ("root", "wheel", "steer_wheel", "hip", "knee", "ankle", "shoulder", "elbow", "pedal")


def joint_angles_many(
    kind: NDArray[np.int64],
    side: NDArray[np.float64],
    wheel_angle_rad: NDArray[np.float64],
    steer_rad: NDArray[np.float64],
    walk_phase_rad: NDArray[np.float64],
    walk_amount: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """`joint_angles` for many joints of many models at once (the renderer's posing on the
    GPU): each argument `(G,)` per joint, `kind` an index into `JOINT_KINDS` (another joint
    kind turns by nothing), the rest its `Joint.side` and its model's `Animation` values;
    returns pitch and yaw `(G,)` in radians."""
    is_kind = {name: kind == index for index, name in enumerate(JOINT_KINDS)}
    hip = side * walk_amount * HIP_SWING_RAD * np.sin(walk_phase_rad)
    knee = walk_amount * KNEE_BEND_RAD * np.maximum(0.0, -side * np.cos(walk_phase_rad))
    pitch = np.select(
        [is_kind["wheel"] | is_kind["steer_wheel"], is_kind["hip"], is_kind["knee"],
         is_kind["ankle"], is_kind["shoulder"], is_kind["elbow"], is_kind["pedal"]],
        [wheel_angle_rad, hip, knee, -(hip + knee),
         -side * walk_amount * ARM_SWING_RAD * np.sin(walk_phase_rad),
         -ELBOW_BEND_RAD * (0.5 + 0.5 * walk_amount),
         side * PEDAL_SWING_RAD * np.sin(wheel_angle_rad)],
        0.0,
    )  # fmt: skip
    yaw = np.where(is_kind["steer_wheel"], np.clip(steer_rad, -STEER_LIMIT_RAD, STEER_LIMIT_RAD),
                   0.0)  # fmt: skip
    return pitch, yaw


def joint_rotations(mesh: ModelMesh, animation: Animation) -> NDArray[np.float64]:
    """`(J, 3, 3)` each joint's rotation about its pivot, in its parent's frame."""
    pitch, yaw = joint_angles(mesh, animation)
    return rotation_z(np.asarray(yaw)) @ rotation_y(np.asarray(pitch))


def _leg_angles(side: int, phase: float, amount: float) -> tuple[float, float]:
    """A leg's hip swing and knee bend (radians) at walk `phase`: the knee bends while its leg
    swings forward (the half cycle before its hip reaches the front)."""
    hip = side * amount * HIP_SWING_RAD * math.sin(phase)
    knee = amount * KNEE_BEND_RAD * max(0.0, -side * math.cos(phase))
    return float(hip), float(knee)


@functools.lru_cache(maxsize=256)
def _chain(
    joint_table: tuple[Joint, ...],
) -> tuple[NDArray[np.float64], NDArray[np.intp], list[NDArray[np.intp]]]:
    """The joints' pivots `(J, 3)`, parents `(J,)` and indices level by level below the root (a
    level's parents all lie in the levels before it), so a whole level is composed at once."""
    depth = [0] * len(joint_table)
    for index, joint in enumerate(joint_table[1:], start=1):
        depth[index] = depth[joint.parent] + 1
    levels = [np.flatnonzero(np.asarray(depth) == level) for level in range(1, max(depth) + 1)]
    pivots = np.array([joint.pivot_m for joint in joint_table], np.float64)
    return pivots, np.array([joint.parent for joint in joint_table]), levels


def chained_transforms(
    rotations: NDArray[np.float64],
    pivots: NDArray[np.float64],
    parents: NDArray[np.intp],
    roots: NDArray[np.intp] | int,
    levels: Sequence[NDArray[np.intp]],
) -> NDArray[np.float64]:
    """`(J, 3, 4)` each joint's transform in its model's frame: a joint turns by its rotation
    `(J, 3, 3)` about its pivot `(J, 3)`, then moves with its parent (`parents` `(J,)`),
    composed level by level (`levels`: index arrays, a level's parents in the levels before
    it); the `roots` stay where they are."""
    transforms = np.empty((len(rotations), 3, 4))
    # a joint's own transform [R | p - R p], then its parent's applied: parent @ own
    transforms[:, :, :3] = rotations
    transforms[:, :, 3] = pivots - (rotations @ pivots[:, :, None])[:, :, 0]
    transforms[roots] = np.eye(3, 4)
    for level in levels:
        parent = transforms[parents[level]]
        own = transforms[level]
        translation = (parent[:, :, :3] @ own[:, :, 3:])[:, :, 0] + parent[:, :, 3]
        transforms[level, :, :3] = parent[:, :, :3] @ own[:, :, :3]
        transforms[level, :, 3] = translation
    return transforms


def joint_transforms(mesh: ModelMesh, animation: Animation) -> NDArray[np.float64]:
    """`(J, 3, 4)` each joint's transform in the model frame (parents before children): a
    joint turns by its rotation about its pivot, then moves with its parent."""
    pivots, parents, levels = _chain(mesh.joint_table)
    return chained_transforms(joint_rotations(mesh, animation), pivots, parents, 0, levels)


class JointChains:
    """The joints of many models as one table, posed together: each model's `joint_transforms`,
    for all of them in a few array operations (one model at a time, a synthetic clip's 18
    shown models had cost 1.5 ms a frame of numpy calls on 2 cores, together 0.6; what the
    renderer poses on the GPU reads). Joint rows in the order of the models, each model's from
    its first; `owner` `(G,)` the model of each."""

    def __init__(self, models: Sequence[ModelMesh]) -> None:
        kinds: list[int] = []
        sides: list[float] = []
        owners: list[int] = []
        pivots, parents, roots = [np.zeros((0, 3))], [np.zeros(0, np.intp)], []
        by_depth: dict[int, list[NDArray[np.intp]]] = {}
        first = 0
        for owner, model in enumerate(models):
            table = model.joint_table
            model_pivots, model_parents, model_levels = _chain(table)
            kinds += [JOINT_KINDS.index(j.kind) if j.kind in JOINT_KINDS else -1 for j in table]
            sides += [float(joint.side) for joint in table]
            owners += [owner] * len(table)
            pivots.append(model_pivots)
            parents.append(first + model_parents)
            roots.append(first)
            for depth, level in enumerate(model_levels):
                by_depth.setdefault(depth, []).append(first + level)
            first += len(table)
        self.kind = np.asarray(kinds, np.int64)
        self.side = np.asarray(sides, np.float64)
        self.owner = np.asarray(owners, np.int64)
        self.pivot = np.concatenate(pivots)
        self.parent = np.concatenate(parents)
        self.roots = np.asarray(roots, np.intp)
        self.levels = [np.concatenate(by_depth[depth]) for depth in sorted(by_depth)]

    def transforms(self, animations: Sequence[Animation]) -> NDArray[np.float64]:
        """`(G, 3, 4)` every joint's `joint_transforms`, model k posed by `animations[k]`."""
        values = np.array([(a.wheel_angle_rad, a.steer_rad, a.walk_phase_rad, a.walk_amount)
                           for a in animations], np.float64).reshape(-1, 4)[self.owner]  # fmt: skip
        pitch, yaw = joint_angles_many(self.kind, self.side, *values.T)
        rotations = rotation_z(yaw) @ rotation_y(pitch)
        return chained_transforms(rotations, self.pivot, self.parent, self.roots, self.levels)


def emission_levels(animation: Animation) -> tuple[float, float, float]:
    """The emission in [0, 1] of each kind of vertex (`ModelMesh.lights`: none, headlight,
    tail light): headlights when on, tail lights dim with the headlights and full when
    braking."""
    tail = 1.0 if animation.brake else (TAIL_GLOW if animation.headlights else 0.0)
    return 0.0, 1.0 if animation.headlights else 0.0, tail


def emission(mesh: ModelMesh, animation: Animation) -> NDArray[np.float32]:
    """`(N,)` each vertex's emission in [0, 1] (`emission_levels`)."""
    return np.array(emission_levels(animation), np.float32)[mesh.lights]


def pose(
    mesh: ModelMesh, animation: Animation
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """The model at one instant: `(N, 3)` positions and normals in the model frame and `(N,)`
    emissions."""
    if len(mesh.joint_table) == 1:
        return mesh.positions, mesh.normals, emission(mesh, animation)
    transforms = joint_transforms(mesh, animation).astype(np.float32)
    chosen = transforms[mesh.joints]
    positions = np.einsum("nij,nj->ni", chosen[:, :, :3], mesh.positions) + chosen[:, :, 3]
    normals = np.einsum("nij,nj->ni", chosen[:, :, :3], mesh.normals)
    return positions.astype(np.float32), normals.astype(np.float32), emission(mesh, animation)
