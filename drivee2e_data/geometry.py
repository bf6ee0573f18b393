"""Planar and spatial geometry on numpy arrays: angles, SE(2) frames, quaternions, polylines, boxes.

Conventions (ARCHITECTURE.md): metres and radians, yaw counter-clockwise from +x, world frame is
the local ENU frame of the intersection. Every function is pure and vectorised where it matters.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def wrap_angle(angle_rad: FloatArray | float) -> FloatArray:
    """Angles wrapped to [-pi, pi)."""
    return (np.asarray(angle_rad, dtype=np.float64) + np.pi) % (2.0 * np.pi) - np.pi


def rotation_2d(yaw_rad: float) -> FloatArray:
    """(2, 2) rotation matrix turning vectors counter-clockwise by `yaw_rad`."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array([[c, -s], [s, c]])


def to_local_frame(xy_m: FloatArray, origin_xy_m: FloatArray, yaw_rad: float) -> FloatArray:
    """Points `xy_m: (N, 2)` expressed in the frame at `origin_xy_m` with heading `yaw_rad`."""
    return (np.asarray(xy_m, dtype=np.float64) - origin_xy_m) @ rotation_2d(yaw_rad)


def to_world_frame(local_xy_m: FloatArray, origin_xy_m: FloatArray, yaw_rad: float) -> FloatArray:
    """Inverse of `to_local_frame`: local points `(N, 2)` back to the world frame."""
    return np.asarray(local_xy_m, dtype=np.float64) @ rotation_2d(yaw_rad).T + origin_xy_m


def quaternion_from_yaw(yaw_rad: FloatArray | float) -> FloatArray:
    """Quaternions `(..., 4)` as (w, x, y, z) for rotations about +z."""
    half = 0.5 * np.asarray(yaw_rad, dtype=np.float64)
    zeros = np.zeros_like(half)
    return np.stack([np.cos(half), zeros, zeros, np.sin(half)], axis=-1)


def yaw_from_quaternion(quaternion_wxyz: FloatArray) -> FloatArray:
    """Heading (rotation about +z) of quaternions `(..., 4)` given as (w, x, y, z)."""
    q = np.asarray(quaternion_wxyz, dtype=np.float64)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def rotation_from_quaternion(quaternion_wxyz: FloatArray) -> FloatArray:
    """Rotation matrices `(..., 3, 3)` of unit quaternions `(..., 4)` given as (w, x, y, z)."""
    q = np.asarray(quaternion_wxyz, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def quaternion_from_rotation(rotation: FloatArray) -> FloatArray:
    """The unit quaternion (w, x, y, z) of a 3x3 rotation matrix, w >= 0."""
    m = np.asarray(rotation, dtype=np.float64)
    trace = np.trace(m)
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
        q = [0.0, 0.0, 0.0, 0.0]
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + k] = (m[k, i] + m[i, k]) / s
    result = np.array(q)
    return result if result[0] >= 0 else -result


def polyline_arclength(points_m: FloatArray) -> FloatArray:
    """Cumulative arclength `(N,)` of a polyline `(N, D)`, starting at 0."""
    segments = np.linalg.norm(np.diff(points_m, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(segments)])


def polyline_headings(points_m: FloatArray) -> FloatArray:
    """Heading `(N,)` of a polyline `(N, 2+)` at each vertex (last vertex repeats its segment)."""
    delta = np.diff(points_m[:, :2], axis=0)
    seg = np.arctan2(delta[:, 1], delta[:, 0])
    return np.concatenate([seg, seg[-1:]])


def resample_polyline(points_m: FloatArray, spacing_m: float) -> FloatArray:
    """The polyline `(N, D)` resampled at a uniform arclength step, keeping both end points."""
    s = polyline_arclength(points_m)
    count = max(2, int(np.ceil(s[-1] / spacing_m)) + 1)
    s_new = np.linspace(0.0, s[-1], count)
    return np.stack([np.interp(s_new, s, points_m[:, d]) for d in range(points_m.shape[1])], -1)


def interpolate_polyline(
    points_m: FloatArray, arclength_m: FloatArray, s_query_m: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Positions `(Q, 2)` and headings `(Q,)` at arclengths `s_query_m: (Q,)` along a polyline.

    `arclength_m` is `polyline_arclength(points_m)`; queries are clamped to the polyline's ends.
    Headings are those of the segment holding each query, so they are exact on straight parts.
    """
    s_query = np.clip(np.asarray(s_query_m, dtype=np.float64), 0.0, arclength_m[-1])
    x = np.interp(s_query, arclength_m, points_m[:, 0])
    y = np.interp(s_query, arclength_m, points_m[:, 1])
    segment = np.clip(np.searchsorted(arclength_m, s_query, side="right") - 1, 0, len(points_m) - 2)
    delta = points_m[segment + 1, :2] - points_m[segment, :2]
    return np.stack([x, y], axis=-1), np.arctan2(delta[:, 1], delta[:, 0])


def offset_polyline(points_m: FloatArray, offset_m: float) -> FloatArray:
    """The polyline `(N, 2)` shifted sideways by `offset_m` (positive to the left of travel)."""
    delta = np.gradient(points_m[:, :2], axis=0)
    normal = np.stack([-delta[:, 1], delta[:, 0]], axis=-1)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return points_m[:, :2] + offset_m * normal


def cubic_bezier(
    p0: FloatArray, p1: FloatArray, p2: FloatArray, p3: FloatArray, count: int
) -> FloatArray:
    """`count` points `(count, 2)` on the cubic Bezier curve with control points p0..p3."""
    t = np.linspace(0.0, 1.0, count)[:, None]
    return (1 - t) ** 3 * p0 + 3 * (1 - t) ** 2 * t * p1 + 3 * (1 - t) * t**2 * p2 + t**3 * p3


def polyline_curvature(points_m: FloatArray) -> FloatArray:
    """Unsigned curvature `(N,)` (1/m) of a densely sampled polyline `(N, 2)`."""
    dx, dy = np.gradient(points_m[:, 0]), np.gradient(points_m[:, 1])
    ddx, ddy = np.gradient(dx), np.gradient(dy)
    return np.abs(dx * ddy - dy * ddx) / np.maximum((dx * dx + dy * dy) ** 1.5, 1e-12)


def box_corners_2d(
    center_xy_m: FloatArray, yaw_rad: FloatArray, length_m: FloatArray, width_m: FloatArray
) -> FloatArray:
    """Corners `(..., 4, 2)` of oriented boxes, counter-clockwise from front-left.

    `center_xy_m: (..., 2)`, `yaw_rad`, `length_m`, `width_m`: `(...)`.
    """
    center = np.asarray(center_xy_m, dtype=np.float64)
    half_l = 0.5 * np.asarray(length_m, dtype=np.float64)[..., None]
    half_w = 0.5 * np.asarray(width_m, dtype=np.float64)[..., None]
    signs = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    local = np.stack([signs[:, 0] * half_l, signs[:, 1] * half_w], axis=-1)  # (..., 4, 2)
    c, s = np.cos(yaw_rad)[..., None], np.sin(yaw_rad)[..., None]
    world_x = local[..., 0] * c - local[..., 1] * s
    world_y = local[..., 0] * s + local[..., 1] * c
    return np.stack([world_x, world_y], axis=-1) + center[..., None, :]


def boxes_overlap(corners_a: FloatArray, corners_b: FloatArray) -> NDArray[np.bool_]:
    """Whether pairs of oriented rectangles overlap (separating-axis test), `(...)` booleans.

    `corners_a`, `corners_b`: `(..., 4, 2)` as from `box_corners_2d`. Touching counts as apart.
    """
    overlap = np.ones(np.broadcast_shapes(corners_a.shape[:-2], corners_b.shape[:-2]), bool)
    for corners in (corners_a, corners_b):
        for edge in range(2):
            axis = corners[..., edge + 1, :] - corners[..., edge, :]
            axis = np.stack([-axis[..., 1], axis[..., 0]], axis=-1)[..., None, :]
            proj_a = np.sum(corners_a * axis, axis=-1)
            proj_b = np.sum(corners_b * axis, axis=-1)
            apart = (proj_a.max(-1) <= proj_b.min(-1)) | (proj_b.max(-1) <= proj_a.min(-1))
            overlap &= ~apart
    return overlap


def centerline_between(left_m: FloatArray, right_m: FloatArray) -> FloatArray:
    """Centre line `(M, D)` of two boundaries given in the same direction: their mean after
    resampling both at equal arclength fractions (M = the larger point count, at least 10)."""
    count = max(len(left_m), len(right_m), 10)
    fractions = np.linspace(0.0, 1.0, count)

    def at(points: FloatArray) -> FloatArray:
        s = polyline_arclength(points)
        s = s / s[-1] if s[-1] > 0 else np.linspace(0.0, 1.0, len(points))
        return np.stack([np.interp(fractions, s, points[:, d]) for d in range(points.shape[1])], -1)

    return 0.5 * (at(left_m) + at(right_m))


def next_waypoint(
    route_xy_m: FloatArray, position_xy_m: FloatArray, min_distance_m: float
) -> FloatArray:
    """(2,) the first route waypoint at least `min_distance_m` from `position_xy_m`, counting
    from the waypoint nearest it (the route's last waypoint when none is that far).
    `route_xy_m: (W >= 1, 2)`."""
    route = np.asarray(route_xy_m, np.float64)
    distance = np.hypot(*(route - np.asarray(position_xy_m, np.float64)).T)
    nearest = int(np.argmin(distance))
    ahead = np.flatnonzero(distance[nearest:] >= min_distance_m)
    return route[nearest + ahead[0]] if len(ahead) else route[-1]
