"""Driving paths through a layout and the places where two paths, or a path and a crossing, meet.

A vehicle's path is its approach lane, a movement through the junction and its exit lane, as one
polyline sampled every 0.5 m with arclength `s`. Conflict zones are arclength intervals on each
of two paths inside which two vehicles (or a vehicle and a pedestrian) would touch.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import shapely
from numpy.typing import NDArray

from drivee2e_data.geometry import interpolate_polyline, polyline_arclength, resample_polyline
from drivee2e_data.sources.synthetic.layout import Layout, Movement

PATH_SPACING_M = 0.5
CONFLICT_RADIUS_M = 3.2  # centre lines closer than this let two of the widest vehicles touch
MERGE_TAIL_M = 12.0  # how far into the exit lane a merge still counts as a conflict
LATERAL_ACCEL_MPS2 = 2.5  # comfortable lateral acceleration that sets curve speeds
CURVE_BRAKE_MPS2 = 2.0  # deceleration used to slow down ahead of a curve


@dataclass(frozen=True)
class Path:
    movement: Movement
    points_m: NDArray[np.float64]  # (N, 2)
    s_m: NDArray[np.float64]  # (N,) arclength
    stop_s_m: float  # arclength of the stop line
    exit_s_m: float  # arclength where the exit lane starts
    lanes: tuple[tuple[str, float, float], ...]  # (lane or movement id, s start, s end)
    speed_limit_mps: NDArray[np.float64]  # (N,) curve speed with braking look-ahead

    @functools.cached_property
    def length_m(self) -> float:
        return float(self.s_m[-1])  # read a few times per vehicle and step: worked out once

    def pose(
        self, s_query_m: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Positions `(Q, 2)` and headings `(Q,)` at arclengths `s_query_m`."""
        return interpolate_polyline(self.points_m, self.s_m, s_query_m)

    @functools.cached_property
    def _points(self) -> list[list[float]]:
        return self.points_m.tolist()  # `pose_at` reads a point a vehicle and step

    def pose_at(self, s_query_m: float) -> tuple[float, float, float]:
        """(x, y, heading) at one arclength; fast scalar form of `pose` (points are evenly spaced)."""
        points = self._points
        last = len(points) - 1
        position = min(max(s_query_m, 0.0), self.length_m) / self.length_m * last
        k = min(int(position), last - 1)
        t = position - k
        (x0, y0), (x1, y1) = points[k], points[k + 1]
        return x0 + t * (x1 - x0), y0 + t * (y1 - y0), math.atan2(y1 - y0, x1 - x0)

    def speed_limit_at(self, s_query_m: float) -> float:
        last = len(self.s_m) - 1
        k = min(max(int(s_query_m / self.length_m * last), 0), last)
        return float(self.speed_limit_mps[k])


@dataclass(frozen=True)
class Zone:
    """On path `this`, the interval [start, end] conflicts with [other_start, other_end] on `other`."""

    other: str
    start_m: float
    end_m: float
    other_start_m: float
    other_end_m: float


@dataclass
class PathNetwork:
    """Every movement's path and the pairwise conflict zones between them."""

    paths: dict[str, Path]
    zones: dict[str, list[Zone]]
    crossing_zones: dict[tuple[str, str], tuple[float, float] | None] = field(default_factory=dict)

    def crossing_zone(
        self, movement_id: str, crossing_id: str, polygon: shapely.Geometry
    ) -> tuple[float, float] | None:
        """Arclength interval of a path that passes within reach of a pedestrian crossing."""
        key = (movement_id, crossing_id)
        if key not in self.crossing_zones:
            path = self.paths[movement_id]
            reach = polygon.buffer(2.0)
            inside = shapely.contains_xy(reach, path.points_m[:, 0], path.points_m[:, 1])
            self.crossing_zones[key] = (
                (float(path.s_m[inside].min()), float(path.s_m[inside].max()))
                if inside.any()
                else None
            )
        return self.crossing_zones[key]


def build_network(layout: Layout) -> PathNetwork:
    paths = {m.movement_id: _path(layout, m) for m in layout.movements}
    zones: dict[str, list[Zone]] = {key: [] for key in paths}
    keys = sorted(paths)
    for i, key_a in enumerate(keys):
        for key_b in keys[i + 1 :]:
            found = _conflict(paths[key_a], paths[key_b])
            if found is not None:
                zone_a, zone_b = found
                zones[key_a].append(Zone(key_b, *zone_a, *zone_b))
                zones[key_b].append(Zone(key_a, *zone_b, *zone_a))
    return PathNetwork(paths, zones)


def _path(layout: Layout, movement: Movement) -> Path:
    entry_lane = layout.intersection_map.lane(movement.from_lane)
    exit_lane = layout.intersection_map.lane(movement.to_lane)
    approach = entry_lane.centerline_m[:, :2]
    departure = exit_lane.centerline_m[:, :2]
    approach_length = float(polyline_arclength(approach)[-1])
    junction_length = float(polyline_arclength(movement.path_m)[-1])
    points = np.concatenate([approach[:-1], movement.path_m, departure[1:]])
    points = resample_polyline(points, PATH_SPACING_M)
    s = polyline_arclength(points)
    stop_s, exit_s = approach_length, approach_length + junction_length
    junction_id = movement.lane_id or movement.movement_id
    lanes = (
        (movement.from_lane, 0.0, stop_s),
        (junction_id, stop_s, exit_s),
        (movement.to_lane, exit_s, float(s[-1])),
    )
    return Path(movement, points, s, stop_s, exit_s, lanes, _speed_profile(points, s))


def _speed_profile(points: NDArray[np.float64], s: NDArray[np.float64]) -> NDArray[np.float64]:
    heading = np.unwrap(np.arctan2(np.gradient(points[:, 1]), np.gradient(points[:, 0])))
    curvature = np.abs(np.gradient(heading, s))
    curvature = np.convolve(curvature, np.ones(5) / 5, mode="same")  # smooth the 0.5 m sampling
    limit = np.sqrt(LATERAL_ACCEL_MPS2 / np.maximum(curvature, 1e-6))
    limit = np.minimum(limit, 30.0)
    for k in range(len(limit) - 2, -1, -1):  # brake ahead of curves
        ds = s[k + 1] - s[k]
        limit[k] = min(limit[k], np.sqrt(limit[k + 1] ** 2 + 2 * CURVE_BRAKE_MPS2 * ds))
    return limit


def _conflict(a: Path, b: Path) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """Conflict intervals of two paths in the junction (and a merge's first metres), if any."""
    in_a = (a.s_m >= a.stop_s_m - 1.0) & (a.s_m <= a.exit_s_m + MERGE_TAIL_M)
    in_b = (b.s_m >= b.stop_s_m - 1.0) & (b.s_m <= b.exit_s_m + MERGE_TAIL_M)
    points_a, points_b = a.points_m[in_a], b.points_m[in_b]
    distance = np.linalg.norm(points_a[:, None, :] - points_b[None, :, :], axis=-1)
    close = distance < CONFLICT_RADIUS_M
    if not close.any():
        return None
    s_a, s_b = a.s_m[in_a][close.any(axis=1)], b.s_m[in_b][close.any(axis=0)]
    return (float(s_a.min()), float(s_a.max())), (float(s_b.min()), float(s_b.max()))
