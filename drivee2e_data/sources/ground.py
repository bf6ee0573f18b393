"""One ground for every source: an imported map and its clips moved so that the road lies at
z = 0, where the twin draws it.

Waymo, nuPlan and Argoverse 2 record real elevation (a Waymo scene sits about 23 m below its
frame's zero), while the twin's road is flat at 0: cameras mounted at a track's height would sit
under the road. A plane is fitted to the map's lane points (or, for maps without heights, to the
bottoms of the vehicles' boxes) and removed from every height: relative heights are kept (boxes
on the road, kerbs, signal heads above it), a constant offset and a uniform slope go. What is
left (the road's curvature) is the flat-ground error, reported as the fit's residual.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.scenario import Scenario

MIN_POINTS = 10  # fewer points than this fit no plane (the ground stays as the source put it)
FIELD_CELL_M = 2.0  # the residual height field's cell
FIELD_SMOOTHING_M = 4.0  # its Gaussian smoothing: roads curve over tens of metres
HEIGHT_EPSILON_M = 1e-3  # heights all within this of 0 are a flat source already
OUTLIER_MADS = 4.0  # vehicle bottoms farther than this many median deviations are refitted out


@dataclass(frozen=True)
class GroundPlane:
    """The ground's height: z = slope_x x + slope_y y + height_m plus, where the fitted points
    reach, a smooth field of what the plane left (cells of `FIELD_CELL_M` from `field_origin`;
    the road's curvature), fitted to `points` heights from `source` ('lanes', 'vehicles' or
    'flat'); `residual_rms_m` is what the plane alone left, `field_rms_m` what plane and field
    leave (the flat twin's error at the fitted points), metres."""

    slope_x: float
    slope_y: float
    height_m: float
    source: str
    points: int
    residual_rms_m: float
    field_rms_m: float = 0.0
    field_origin: tuple[float, float] = (0.0, 0.0)
    field: NDArray[np.float64] | None = None  # (rows along y, columns along x)

    def at(self, x_m: NDArray[np.float64], y_m: NDArray[np.float64]) -> NDArray[np.float64]:
        x, y = np.asarray(x_m, dtype=np.float64), np.asarray(y_m, dtype=np.float64)
        height = self.slope_x * x + self.slope_y * y + self.height_m
        if self.field is None:
            return height
        return height + _bilinear(self.field, (x - self.field_origin[0]) / FIELD_CELL_M,
                                  (y - self.field_origin[1]) / FIELD_CELL_M)  # fmt: skip


FLAT = GroundPlane(0.0, 0.0, 0.0, "flat", 0, 0.0)


def _bilinear(grid: NDArray[np.float64], column: NDArray, row: NDArray) -> NDArray[np.float64]:
    """`grid` sampled at fractional cell centres (edge values beyond the grid)."""
    rows, columns = grid.shape
    c = np.clip(np.nan_to_num(column - 0.5), 0, columns - 1)
    r = np.clip(np.nan_to_num(row - 0.5), 0, rows - 1)
    c0, r0 = (
        np.minimum(c.astype(int), columns - 2).clip(0),
        np.minimum(r.astype(int), rows - 2).clip(0),
    )
    c1, r1 = np.minimum(c0 + 1, columns - 1), np.minimum(r0 + 1, rows - 1)
    fc, fr = c - c0, r - r0
    top = grid[r0, c0] * (1 - fc) + grid[r0, c1] * fc
    bottom = grid[r1, c0] * (1 - fc) + grid[r1, c1] * fc
    return np.where(np.isnan(column) | np.isnan(row), 0.0, top * (1 - fr) + bottom * fr)


def _residual_field(points: NDArray[np.float64], residual: NDArray[np.float64]):
    """A smooth field of `residual` over the points' extent: the mean per cell, spread by a
    Gaussian (weights alike), zero far from any point. Returns (origin, field)."""
    import cv2

    origin = points[:, :2].min(axis=0) - 3 * FIELD_SMOOTHING_M
    extent = points[:, :2].max(axis=0) + 3 * FIELD_SMOOTHING_M - origin
    columns, rows = (np.ceil(extent / FIELD_CELL_M).astype(int) + 1).tolist()
    cells = np.floor((points[:, :2] - origin) / FIELD_CELL_M).astype(int)
    sums, counts = np.zeros((rows, columns)), np.zeros((rows, columns))
    np.add.at(sums, (cells[:, 1], cells[:, 0]), residual)
    np.add.at(counts, (cells[:, 1], cells[:, 0]), 1.0)
    sigma = FIELD_SMOOTHING_M / FIELD_CELL_M
    sums = cv2.GaussianBlur(sums, (0, 0), sigma)
    counts = cv2.GaussianBlur(counts, (0, 0), sigma)
    field = np.where(counts > 1e-3, sums / np.maximum(counts, 1e-9), 0.0)
    return (float(origin[0]), float(origin[1])), field


def _fit(points: NDArray[np.float64], source: str, robust: bool) -> GroundPlane:
    design = np.column_stack([points[:, 0], points[:, 1], np.ones(len(points))])
    keep = np.ones(len(points), bool)
    for _ in range(2 if robust else 1):
        coefficients, *_ = np.linalg.lstsq(design[keep], points[keep, 2], rcond=None)
        residual = points[:, 2] - design @ coefficients
        deviation = np.median(np.abs(residual[keep] - np.median(residual[keep])))
        keep = np.abs(residual) <= max(OUTLIER_MADS * 1.4826 * deviation, 0.05)
    rms = float(np.sqrt(np.mean(residual[keep] ** 2)))
    plane = GroundPlane(float(coefficients[0]), float(coefficients[1]), float(coefficients[2]),
                        source, int(keep.sum()), rms)  # fmt: skip
    if rms < 0.02:  # a plane: no field needed
        return dataclasses.replace(plane, field_rms_m=rms)
    origin, field = _residual_field(points[keep], residual[keep])
    plane = dataclasses.replace(plane, field_origin=origin, field=field)
    left = points[keep, 2] - plane.at(points[keep, 0], points[keep, 1])
    return dataclasses.replace(plane, field_rms_m=float(np.sqrt(np.mean(left**2))))


def fit_ground(intersection_map: IntersectionMap, scenarios: list[Scenario]) -> GroundPlane:
    """The plane under the map: through its lanes' points where they carry heights, else through
    the bottoms of its clips' motor vehicles' boxes; `FLAT` where neither has heights."""
    lanes = [
        polyline
        for lane in intersection_map.lanes
        for polyline in (lane.centerline_m, lane.left_boundary_m, lane.right_boundary_m)
    ]
    points = np.concatenate(lanes) if lanes else np.zeros((0, 3))
    if len(points) >= MIN_POINTS and np.abs(points[:, 2]).max() > HEIGHT_EPSILON_M:
        return _fit(points, "lanes", robust=False)
    bottoms = []
    for scenario in scenarios:
        for track in scenario.tracks:
            if track.agent_class.is_motor_vehicle:
                valid = track.valid
                bottoms.append(np.column_stack([track.x_m[valid], track.y_m[valid],
                                                track.z_m[valid] - 0.5 * track.height_m[valid]]))  # fmt: skip
    bottoms_array = np.concatenate(bottoms) if bottoms else np.zeros((0, 3))
    if len(bottoms_array) >= MIN_POINTS and np.abs(bottoms_array[:, 2]).max() > HEIGHT_EPSILON_M:
        return _fit(bottoms_array, "vehicles", robust=True)
    return FLAT


def _lowered(points: NDArray[np.float64], plane: GroundPlane) -> NDArray[np.float64]:
    """Points `(N, 3)` with the plane's height under each removed."""
    out = np.array(points, dtype=np.float64, copy=True)
    out[:, 2] -= plane.at(out[:, 0], out[:, 1])
    return out


def level_map(intersection_map: IntersectionMap, plane: GroundPlane) -> IntersectionMap:
    """The map with the plane removed from its lanes, stop lines, kerbs and obstacles (signal
    heads, trees, areas and buildings hold heights above the ground or none); a map whose
    heights were all 0 (the plane came from its vehicles) keeps them, and only its origin's
    altitude moves."""
    if plane is FLAT:
        return intersection_map
    if plane.source != "lanes":
        origin = dataclasses.replace(intersection_map.origin,
                                     altitude_m=intersection_map.origin.altitude_m + plane.height_m)  # fmt: skip
        return dataclasses.replace(intersection_map, origin=origin)
    replace = dataclasses.replace
    lanes = tuple(
        replace(
            lane,
            centerline_m=_lowered(lane.centerline_m, plane),
            left_boundary_m=_lowered(lane.left_boundary_m, plane),
            right_boundary_m=_lowered(lane.right_boundary_m, plane),
        )
        for lane in intersection_map.lanes
    )
    stop_lines = tuple(
        replace(s, line_m=_lowered(s.line_m, plane)) for s in intersection_map.stop_lines
    )
    kerbs = tuple(replace(k, line_m=_lowered(k.line_m, plane)) for k in intersection_map.kerbs)
    obstacles = tuple(
        replace(o, position_m=_lowered(o.position_m[None], plane)[0])
        for o in intersection_map.static_obstacles
    )
    origin = replace(intersection_map.origin,
                     altitude_m=intersection_map.origin.altitude_m + plane.height_m)  # fmt: skip
    return replace(intersection_map, lanes=lanes, stop_lines=stop_lines, kerbs=kerbs,
                   static_obstacles=obstacles, origin=origin)  # fmt: skip


def _median_bottom(tracks, lowered: bool, plane: GroundPlane) -> float:
    bottoms = [
        track.z_m[track.valid] - 0.5 * track.height_m[track.valid]
        - (plane.at(track.x_m[track.valid], track.y_m[track.valid]) if lowered else 0.0)
        for track in tracks
        if track.agent_class.is_motor_vehicle and track.valid.any()
    ]  # fmt: skip
    return float(np.median(np.concatenate(bottoms))) if bottoms else 0.0


def level_scenario(scenario: Scenario, plane: GroundPlane) -> Scenario:
    """The clip with the plane's height under each track point removed from its z, where that
    puts its vehicles on the road; a source that already put its tracks on z = 0 while its map
    keeps elevation (Argoverse 2's forecasting scenarios carry no z) is left as it is."""
    if plane is FLAT:
        return scenario
    if abs(_median_bottom(scenario.tracks, False, plane)) < abs(
        _median_bottom(scenario.tracks, True, plane)
    ):
        return scenario
    tracks = tuple(
        dataclasses.replace(track, z_m=track.z_m - plane.at(track.x_m, track.y_m))
        for track in scenario.tracks
    )
    return dataclasses.replace(scenario, tracks=tracks)


def level(
    maps: list[IntersectionMap], scenarios: list[Scenario]
) -> tuple[list[IntersectionMap], list[Scenario], dict[str, GroundPlane]]:
    """Every map and its clips on the twin's ground; the plane removed per map id."""
    by_map: dict[str, list[Scenario]] = {}
    for scenario in scenarios:
        by_map.setdefault(scenario.map_id, []).append(scenario)
    planes = {m.map_id: fit_ground(m, by_map.get(m.map_id, [])) for m in maps}
    leveled_maps = [level_map(m, planes[m.map_id]) for m in maps]
    leveled = [level_scenario(s, planes.get(s.map_id, FLAT)) for s in scenarios]
    return leveled_maps, leveled, planes
