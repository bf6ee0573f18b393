"""People and what they ride: a jointed figure (head, torso, arms, legs) that walks or stands,
and bicycles, motorcycles and tricycles with a rider, all inside their boxes.

Proportions are fractions of the stature (anthropometric tables put the hip joint at about 0.53
of it, the shoulder at 0.82, the head at 0.13 of it tall); a walk cycle (`mesh.pose`) swings
the hips, bends the knees and swings the arms, its phase the distance walked over the stride.
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.sim.models import palette
from drivee2e_data.sim.models.mesh import (
    Joint,
    Light,
    Material,
    MeshBuilder,
    ModelMesh,
    box,
    cylinder,
    ellipsoid,
)

HIP = 0.53  # hip joint height / stature
KNEE = 0.285
ANKLE = 0.045
SHOULDER = 0.815
ELBOW = 0.63
WRIST = 0.48
NECK = 0.855
HEAD_CENTRE = 0.935
STRIDE_PER_STATURE = 0.83  # a walk cycle (two steps) is about 0.8-0.85 of the stature
LIMB_SIDES = 7
RIDER_STATURE_M = 1.72


def frustum(start: NDArray, end: NDArray, radius_start: float, radius_end: float,
            sides: int = LIMB_SIDES) -> NDArray[np.float64]:  # fmt: skip
    """Triangles of a closed tapered prism from `start` to `end` (a limb). (The cross products
    are written out: `np.cross` on two 3-vectors cost more than the rest of a figure; the same
    operations in the same order, so the same numbers.)"""
    start, end = np.asarray(start, np.float64), np.asarray(end, np.float64)
    axis = end - start
    length = float(np.linalg.norm(axis))
    axis = axis / max(length, 1e-9)
    a0, a1, a2 = axis.tolist()
    h0, h1, h2 = (1.0, 0.0, 0.0) if abs(a0) < 0.9 else (0.0, 1.0, 0.0)
    u = np.array([a1 * h2 - a2 * h1, a2 * h0 - a0 * h2, a0 * h1 - a1 * h0])
    u /= np.linalg.norm(u)
    u0, u1, u2 = u.tolist()
    v = np.array([a1 * u2 - a2 * u1, a2 * u0 - a0 * u2, a0 * u1 - a1 * u0])
    cosines, sines, following = _ring(sides)
    ring = cosines * u + sines * v
    low, high = start + radius_start * ring, end + radius_end * ring
    low_next, high_next = low[following], high[following]
    triangles = np.empty((4, sides, 3, 3))
    triangles[0, :, 0], triangles[0, :, 1], triangles[0, :, 2] = low, low_next, high_next
    triangles[1, :, 0], triangles[1, :, 1], triangles[1, :, 2] = low, high_next, high
    triangles[2, :, 0], triangles[2, :, 1], triangles[2, :, 2] = start, low_next, low
    triangles[3, :, 0], triangles[3, :, 1], triangles[3, :, 2] = end, high, high_next
    return triangles.reshape(-1, 3, 3)


@functools.cache
def _ring(sides: int) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """A limb's section: the cosines and sines `(sides, 1)` of its corners' angles, and each
    corner's next."""
    angles = np.linspace(0.0, 2 * np.pi, sides, endpoint=False)
    following = np.roll(np.arange(sides), -1)
    return np.cos(angles)[:, None], np.sin(angles)[:, None], following


def _person_colours(rng: np.random.Generator) -> dict[str, tuple[float, float, float]]:
    return {
        "skin": palette.pick(palette.SKIN, rng),
        "hair": palette.pick(palette.HAIR, rng),
        "top": palette.pick(palette.CLOTHING, rng),
        "bottom": palette.pick(palette.TROUSERS, rng),
        "shoes": (0.08, 0.07, 0.07),
    }


def walking_figure(stature_m: float, build: float, rng: np.random.Generator) -> ModelMesh:
    """A figure of `stature_m` standing with its feet at z = -stature / 2, centred in x and y
    (the caller sets it on its box's floor); `build` scales its breadth (0.85 slim to 1.15
    broad)."""
    colours = _person_colours(rng)
    builder = MeshBuilder()
    h = stature_m
    ground = -0.5 * h
    z = lambda fraction: ground + fraction * h  # noqa: E731 - heights read as fractions
    hip_half = 0.085 * h * build
    shoulder_half = 0.115 * h * build
    torso_depth = 0.065 * h * build
    # head, neck, torso, pelvis
    builder.add(ellipsoid((0.0, 0.0, z(HEAD_CENTRE)), (0.058 * h, 0.05 * h, 0.065 * h)),
                colours["skin"], smooth=True)  # fmt: skip
    builder.add(ellipsoid((-0.008 * h, 0.0, z(HEAD_CENTRE) + 0.018 * h),
                          (0.056 * h, 0.052 * h, 0.05 * h)), colours["hair"])  # fmt: skip
    builder.add(frustum((0, 0, z(NECK) - 0.02 * h), (0, 0, z(HEAD_CENTRE) - 0.04 * h),
                        0.025 * h, 0.022 * h), colours["skin"])  # fmt: skip
    torso = _torso(z(HIP) + 0.02 * h, z(SHOULDER) + 0.03 * h, hip_half, shoulder_half, torso_depth)
    builder.add(torso, colours["top"], smooth=False)
    builder.add(box((0.0, 0.0, z(HIP) + 0.01 * h), (2 * torso_depth, 2 * hip_half, 0.07 * h)),
                colours["bottom"], smooth=False)  # fmt: skip
    for side in (1, -1):
        y_hip = side * 0.55 * hip_half
        hip = builder.joint(Joint((0.0, y_hip, z(HIP)), "hip", side))
        knee = builder.joint(Joint((0.0, y_hip, z(KNEE)), "knee", side, parent=hip))
        builder.add(frustum((0, y_hip, z(HIP)), (0, y_hip, z(KNEE)), 0.06 * h * build,
                            0.042 * h), colours["bottom"], joint=hip)  # fmt: skip
        builder.add(frustum((0, y_hip, z(KNEE)), (0, y_hip, z(ANKLE)), 0.04 * h, 0.03 * h),
                    colours["bottom"], joint=knee)  # fmt: skip
        ankle = builder.joint(Joint((0.0, y_hip, z(ANKLE)), "ankle", side, parent=knee))
        builder.add(box((0.015 * h, y_hip, z(ANKLE) - 0.0175 * h), (0.09 * h, 0.05 * h, 0.055 * h)),
                    colours["shoes"], joint=ankle, smooth=False)  # fmt: skip
        y_shoulder = side * (shoulder_half + 0.02 * h)
        shoulder = builder.joint(Joint((0.0, y_shoulder, z(SHOULDER)), "shoulder", side))
        elbow = builder.joint(Joint((0.0, y_shoulder, z(ELBOW)), "elbow", side, parent=shoulder))
        builder.add(frustum((0, y_shoulder, z(SHOULDER)), (0, y_shoulder, z(ELBOW)), 0.032 * h,
                            0.027 * h), colours["top"], joint=shoulder)  # fmt: skip
        builder.add(frustum((0, y_shoulder, z(ELBOW)), (0, y_shoulder, z(WRIST)), 0.026 * h,
                            0.021 * h), colours["skin"], joint=elbow)  # fmt: skip
    return builder.build(stride_m=STRIDE_PER_STATURE * h)


def _torso(bottom: float, top: float, hip_half: float, shoulder_half: float,
           depth: float) -> NDArray[np.float64]:  # fmt: skip
    """A torso widening from the hips to the shoulders (an eight-cornered loft)."""
    rings = []
    for z_value, half in (
        (bottom, hip_half),
        (top - 0.06, shoulder_half),
        (top, 0.7 * shoulder_half),
    ):
        outline = np.array([(depth, half * 0.7), (0.6 * depth, half), (-0.6 * depth, half),
                            (-depth, half * 0.7), (-depth, -half * 0.7), (-0.6 * depth, -half),
                            (0.6 * depth, -half), (depth, -half * 0.7)])  # fmt: skip
        rings.append(np.column_stack([outline, np.full(8, z_value)]))
    triangles = []
    for lower, upper in itertools.pairwise(rings):
        lower_next, upper_next = np.roll(lower, -1, 0), np.roll(upper, -1, 0)
        triangles += [
            np.stack([lower, lower_next, upper_next], 1),
            np.stack([lower, upper_next, upper], 1),
        ]
    for ring, flip in ((rings[0], True), (rings[-1], False)):
        centre = np.broadcast_to(ring.mean(axis=0), ring.shape)
        fan = np.stack([centre, ring, np.roll(ring, -1, 0)], 1)
        triangles.append(fan[:, ::-1] if flip else fan)
    return np.concatenate(triangles)


def rider(builder: MeshBuilder, seat: NDArray, pedal: NDArray, grip: NDArray, stature_m: float,
          colours: dict, helmet: tuple | None) -> None:  # fmt: skip
    """A seated rider: hips on `seat`, feet at `pedal` (swinging with the wheels: `pedal`
    joints), hands on `grip` (points in the model frame; the rider is symmetric in y)."""
    h = stature_m
    seat, pedal, grip = (np.asarray(v, np.float64) for v in (seat, pedal, grip))
    lean = grip[0] - seat[0]
    torso_length = (SHOULDER - HIP) * h
    reach = np.array([lean * 0.55, 0.0, 0.0])
    up = np.sqrt(max(torso_length**2 - reach[0] ** 2, 0.04 * torso_length**2))
    shoulder = seat + reach + np.array([0.0, 0.0, up])
    builder.add(
        frustum(seat + np.array([0, 0, 0.03]), shoulder, 0.09 * h, 0.1 * h, sides=8), colours["top"]
    )
    head = shoulder + np.array([0.03 * h, 0.0, 0.1 * h])
    builder.add(ellipsoid(head, (0.058 * h, 0.05 * h, 0.065 * h)), colours["skin"])
    top = helmet if helmet is not None else colours["hair"]
    builder.add(
        ellipsoid(head + np.array([-0.005 * h, 0, 0.02 * h]), (0.062 * h, 0.055 * h, 0.055 * h)),
        top,
    )
    for side in (1, -1):
        offset = np.array([0.0, side * 0.07 * h, 0.0])
        hip_point = seat + offset
        foot = pedal + offset
        knee = 0.5 * (hip_point + foot) + np.array([0.12 * h, 0.0, 0.05 * h])
        joint = builder.joint(Joint(tuple(hip_point), "pedal", side))
        builder.add(frustum(hip_point, knee, 0.055 * h, 0.04 * h), colours["bottom"], joint=joint)
        builder.add(frustum(knee, foot, 0.04 * h, 0.03 * h), colours["bottom"], joint=joint)
        shoulder_point = shoulder + np.array([0.0, side * 0.11 * h, -0.02 * h])
        hand = grip + np.array([0.0, side * 0.02 * h, 0.0])
        elbow = 0.5 * (shoulder_point + hand) + np.array([0.0, 0.0, -0.04 * h])
        builder.add(frustum(shoulder_point, elbow, 0.03 * h, 0.026 * h), colours["top"])
        builder.add(frustum(elbow, hand, 0.026 * h, 0.02 * h), colours["skin"])


def spoked_wheel(builder: MeshBuilder, centre: NDArray, radius: float, steers: bool,
                 spokes: int = 8) -> None:  # fmt: skip
    """A thin tyre (a ring of segments) with spokes, turning about its own joint."""
    joint = builder.joint(
        Joint(tuple(float(v) for v in centre), "steer_wheel" if steers else "wheel")
    )
    segments = 16
    angles = np.linspace(0.0, 2 * np.pi, segments + 1)
    points = np.column_stack([np.cos(angles), np.zeros_like(angles), np.sin(angles)]) * (
        0.92 * radius
    )
    for a, b in itertools.pairwise(points):
        builder.add(frustum(centre + a, centre + b, 0.08 * radius, 0.08 * radius, sides=5),
                    palette.TYRE_RGB, Material.TYRE, joint=joint)  # fmt: skip
    for k in range(spokes):
        angle = np.pi * k / spokes
        tip = np.array([np.cos(angle), 0.0, np.sin(angle)]) * 0.85 * radius
        builder.add(frustum(centre - tip, centre + tip, 0.01, 0.01, sides=3), palette.RIM_RGB,
                    Material.PAINT, joint=joint, smooth=False)  # fmt: skip


def two_wheeler(size_m: NDArray, motor: bool, rng: np.random.Generator) -> ModelMesh:
    """A bicycle (or motorcycle) with its rider, filling the box's length and height."""
    length, _, height = size_m
    builder = MeshBuilder()
    ground = -0.5 * height
    radius = (0.31 if motor else 0.34) * min(1.0, length / 1.8)
    rear = np.array([-0.5 * length + radius, 0.0, ground + radius])
    front = np.array([0.5 * length - radius, 0.0, ground + radius])
    colours = _person_colours(rng)
    frame = palette.pick(palette.CARGO_COLOURS if motor else palette.CLOTHING, rng)
    if motor:
        for centre, steers in ((rear, False), (front, True)):
            joint = builder.joint(Joint(tuple(centre), "steer_wheel" if steers else "wheel"))
            builder.add(cylinder(centre, radius, 0.12, axis=1, sides=16), palette.TYRE_RGB,
                        Material.TYRE, joint=joint)  # fmt: skip
            builder.add(cylinder(centre, 0.6 * radius, 0.14, axis=1, sides=10), palette.RIM_RGB,
                        Material.PAINT, joint=joint, smooth=False)  # fmt: skip
        builder.add(ellipsoid(front * [0.25, 0, 1] + [0, 0, 0.55 * radius],
                              (0.32, 0.15, 0.14)), frame, Material.PAINT)  # tank  # fmt: skip
        builder.add(box((0.0, 0.0, ground + 1.1 * radius), (0.5, 0.26, 0.32)), palette.TRIM_RGB,
                    smooth=False)  # engine  # fmt: skip
        builder.add(frustum(rear + np.array([0.25, 0, 0.75 * radius]), rear + np.array([0.7, 0, 0.85 * radius]), 0.1,
                            0.1, sides=6), (0.1, 0.1, 0.1))  # seat  # fmt: skip
        builder.add(
            frustum(front, front + np.array([-0.22, 0, 1.9 * radius]), 0.03, 0.03), palette.RIM_RGB
        )
        builder.add(box(front + np.array([-0.12, 0, 1.6 * radius]), (0.12, 0.16, 0.1)), palette.HEADLIGHT_RGB,
                    Material.LAMP, Light.HEAD, smooth=False)  # fmt: skip
        builder.add(box(rear + np.array([-radius + 0.04, 0, 1.3 * radius]), (0.06, 0.12, 0.06)),
                    palette.TAIL_RGB, Material.LAMP, Light.TAIL, smooth=False)  # fmt: skip
        seat = rear + np.array([0.5, 0.0, 0.95 * radius])
        pedal = np.array([0.05, 0.0, ground + 0.9 * radius])
    else:
        for centre, steers in ((rear, False), (front, True)):
            spoked_wheel(builder, centre, radius, steers)
        crank = np.array([-0.05 * length, 0.0, ground + 0.85 * radius])
        seat_post = rear + np.array([0.32 * length, 0.0, 1.45 * radius])
        head_tube = front + np.array([-0.12 * length, 0.0, 1.55 * radius])
        for a, b in ((rear, crank), (rear, seat_post), (crank, seat_post), (crank, head_tube),
                     (seat_post, head_tube), (head_tube, front)):  # fmt: skip
            builder.add(frustum(a, b, 0.022, 0.022, sides=5), frame, Material.PAINT)
        builder.add(
            box(seat_post + np.array([0, 0, 0.04]), (0.22, 0.1, 0.05)),
            (0.08, 0.08, 0.08),
            smooth=False,
        )
        seat = seat_post + np.array([0.0, 0.0, 0.08])
        pedal = crank
    grip = front + np.array([-0.22 * length, 0.0, (1.95 if motor else 2.05) * radius])
    builder.add(frustum(grip + np.array([0, 0.28, 0]), grip + np.array([0, -0.28, 0]), 0.015, 0.015, sides=4),
                (0.1, 0.1, 0.1))  # fmt: skip
    stature = min(RIDER_STATURE_M, height * 1.05)
    rider(builder, seat, pedal, grip, stature, colours,
          palette.pick(palette.CLOTHING, rng) if motor else None)  # fmt: skip
    return _fit_height(builder.build(wheel_radius_m=radius), height)


def tricycle(size_m: NDArray, rng: np.random.Generator) -> ModelMesh:
    """A cargo tricycle: one steering wheel in front, two behind under a cargo box, a rider."""
    length, width, height = size_m
    builder = MeshBuilder()
    ground = -0.5 * height
    radius = 0.3
    front = np.array([0.5 * length - radius, 0.0, ground + radius])
    rear_x = -0.5 * length + 0.55
    spoked_wheel(builder, front, radius, True)
    for side in (1, -1):
        centre = np.array([rear_x, side * (0.5 * width - 0.06), ground + radius])
        spoked_wheel(builder, centre, radius, False)
    cargo = palette.pick(palette.CARGO_COLOURS, rng)
    box_length = 0.45 * length
    builder.add(box((-0.5 * length + 0.5 * box_length, 0.0, ground + 2 * radius + 0.3),
                    (box_length, width - 0.2, 0.6)), cargo, Material.PAINT, smooth=False)  # fmt: skip
    builder.add(box((-0.5 * length + 0.03, 0.0, ground + 2 * radius + 0.1), (0.06, 0.5, 0.06)),
                palette.TAIL_RGB, Material.LAMP, Light.TAIL, smooth=False)  # fmt: skip
    frame = palette.pick(palette.CLOTHING, rng)
    seat = np.array([-0.5 * length + box_length + 0.25, 0.0, ground + 0.95])
    crank = np.array([seat[0] + 0.35, 0.0, ground + 0.3])
    head_tube = front + np.array([-0.25, 0.0, 0.55])
    for a, b in ((seat + np.array([0, 0, -0.05]), crank), (crank, head_tube), (head_tube, front),
                 (seat + np.array([0, 0, -0.05]), np.array([rear_x + 0.3, 0, ground + radius + 0.2])),
                 (seat + np.array([0, 0, -0.05]), head_tube)):  # fmt: skip
        builder.add(frustum(a, b, 0.025, 0.025, sides=5), frame, Material.PAINT)
    grip = head_tube + np.array([-0.05, 0.0, 0.12])
    builder.add(frustum(grip + np.array([0, 0.28, 0]), grip + np.array([0, -0.28, 0]), 0.015, 0.015, sides=4),
                (0.1, 0.1, 0.1))  # fmt: skip
    rider(builder, seat, crank, grip, min(RIDER_STATURE_M, height), _person_colours(rng), None)
    return _fit_height(builder.build(wheel_radius_m=radius), height)


def _fit_height(mesh: ModelMesh, height: float) -> ModelMesh:
    """The mesh scaled down about its ground point where its top pokes above the box."""
    top = float(mesh.positions[:, 2].max())
    ground = -0.5 * height
    if top <= 0.5 * height:
        return mesh
    scale = (0.5 * height - ground) / (top - ground)
    positions = mesh.positions.copy()
    positions[:, 2] = ground + (positions[:, 2] - ground) * scale
    joints = tuple(
        replace(j, pivot_m=(j.pivot_m[0], j.pivot_m[1], ground + (j.pivot_m[2] - ground) * scale))
        for j in mesh.joint_table
    )
    return replace(mesh, positions=positions, joint_table=joints,
                   wheel_radius_m=mesh.wheel_radius_m * scale)  # fmt: skip
