"""Vector map labels as VAD-style planners learn them: lane dividers, pedestrian crossings and
road boundaries as polylines around the ego, each resampled to a fixed number of points.

From an `IntersectionMap` (world frame), once per map:

- `boundary`: the edges of the road, the outline of the union of every lane's surface and the
  drivable areas;
- `divider`: lane boundaries off the road's edge (between two lanes), outside junctions, each
  line once where two lanes share it;
- `ped_crossing`: the outline of each crosswalk.

Per sample the polylines are moved into the LiDAR frame, cut to a patch centred on the LiDAR
(60 m along x, forward, by 30 m along y, as VAD's default), and every piece longer than
`MIN_PIECE_M` is resampled to `points` points evenly spaced along it. `bev_segmentation`
rasterises the same map around the LiDAR for UniAD-style BEV heads.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import shapely
from numpy.typing import NDArray

from drivee2e_data.hdmap import IntersectionMap

MAP_CLASSES = ("divider", "ped_crossing", "boundary")  # gt_map_labels index this (VAD's order)
DEFAULT_PATCH_M = (60.0, 30.0)  # along the LiDAR's x (forward) and y (left)
DEFAULT_POINTS = 20
MIN_PIECE_M = 0.5  # shorter pieces left by the patch's edge are dropped
EDGE_TOLERANCE_M = 0.3  # a lane boundary this close to the road's edge is the edge, no divider
SAME_LINE_M = 0.2  # two lanes' boundaries this close (Hausdorff) are one divider


BEV_LAYERS = ("drivable_area", "lane_line", "ped_crossing")  # gt_bev_seg channels


@dataclass(frozen=True)
class MapElements:
    """An intersection's labelled polylines `(N, 2)` with class indices, its road surface and
    crosswalk outlines, world frame."""

    polylines_m: tuple[NDArray[np.float64], ...]
    labels: tuple[int, ...]
    road: shapely.Geometry
    crosswalks_m: tuple[NDArray[np.float64], ...]


def map_elements(intersection_map: IntersectionMap) -> MapElements:
    """Dividers, crossings and road boundaries of a map (see the module docstring)."""
    surfaces = [
        shapely.Polygon(np.vstack([lane.left_boundary_m[:, :2], lane.right_boundary_m[::-1, :2]]))
        for lane in intersection_map.lanes
    ]
    surfaces += [shapely.Polygon(a.polygon_m[:, :2]) for a in intersection_map.drivable_areas]
    road = shapely.unary_union([shapely.make_valid(s).buffer(0.01) for s in surfaces])
    edges = shapely.boundary(road)
    polylines: list[NDArray[np.float64]] = []
    labels: list[int] = []
    kept: list[shapely.LineString] = []
    for lane in intersection_map.lanes:
        if lane.is_intersection:
            continue
        for side in (lane.left_boundary_m, lane.right_boundary_m):
            line = shapely.LineString(side[:, :2])
            if line.length < MIN_PIECE_M or line.hausdorff_distance(edges) < EDGE_TOLERANCE_M:
                continue  # on the road's edge: that is a boundary, labelled below
            if any(line.hausdorff_distance(other) < SAME_LINE_M for other in kept):
                continue
            kept.append(line)
            polylines.append(np.asarray(line.coords))
            labels.append(MAP_CLASSES.index("divider"))
    for crosswalk in intersection_map.crosswalks:
        ring = shapely.Polygon(crosswalk.polygon_m[:, :2]).exterior
        polylines.append(np.asarray(ring.coords))
        labels.append(MAP_CLASSES.index("ped_crossing"))
    for part in shapely.get_parts(edges):
        polylines.append(np.asarray(part.coords)[:, :2])
        labels.append(MAP_CLASSES.index("boundary"))
    crossings = tuple(
        np.asarray(c.polygon_m[:, :2], np.float64) for c in intersection_map.crosswalks
    )
    return MapElements(tuple(polylines), tuple(labels), road, crossings)


def map_labels(
    elements: MapElements,
    lidar_to_world: NDArray[np.float64],
    patch_m: tuple[float, float] = DEFAULT_PATCH_M,
    points: int = DEFAULT_POINTS,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """`(K, points, 2)` polylines in the LiDAR frame inside the patch, and `(K,)` labels."""
    rotation, origin = lidar_to_world[:2, :2], lidar_to_world[:2, 3]
    patch = shapely.box(-patch_m[0] / 2, -patch_m[1] / 2, patch_m[0] / 2, patch_m[1] / 2)
    reach = 0.5 * float(np.hypot(*patch_m))  # no part of the patch is farther from its centre
    centre = shapely.Point(0.0, 0.0)
    pieces: list[NDArray[np.float64]] = []
    labels: list[int] = []
    for polyline, label in zip(elements.polylines_m, elements.labels, strict=True):
        line = shapely.LineString((polyline - origin) @ rotation)
        if line.distance(centre) > reach:
            continue
        for piece in shapely.get_parts(shapely.intersection(line, patch)):
            if piece.geom_type != "LineString" or piece.length < MIN_PIECE_M:
                continue
            spots = [piece.interpolate(d, normalized=True) for d in np.linspace(0.0, 1.0, points)]
            pieces.append(np.array([(p.x, p.y) for p in spots]))
            labels.append(label)
    if not pieces:
        return np.zeros((0, points, 2)), np.zeros(0, np.int64)
    return np.stack(pieces), np.array(labels, np.int64)


def bev_segmentation(
    elements: MapElements,
    lidar_to_world: NDArray[np.float64],
    size_px: int,
    resolution_m: float,
) -> NDArray[np.uint8]:
    """(3, size, size) 0/1 masks around the LiDAR, its x up the image and y to the left (row 0
    is the farthest ahead, column 0 the farthest left): drivable area, lane lines (dividers and
    road boundaries, one pixel wide), pedestrian crossings. A pixel covers `resolution_m`."""
    rotation, origin = lidar_to_world[:2, :2], lidar_to_world[:2, 3]

    def pixels(world_xy: NDArray[np.float64]) -> NDArray[np.int32]:
        local = (np.asarray(world_xy)[:, :2] - origin) @ rotation
        column = size_px / 2 - local[:, 1] / resolution_m
        row = size_px / 2 - local[:, 0] / resolution_m
        return np.round(np.column_stack([column, row]) * 16).astype(np.int32)  # 4 fractional bits

    layers = np.zeros((3, size_px, size_px), np.uint8)
    for polygon in shapely.get_parts(elements.road):
        rings = [pixels(np.asarray(polygon.exterior.coords))]
        cv2.fillPoly(layers[0], rings, 1, shift=4)
        holes = [pixels(np.asarray(ring.coords)) for ring in polygon.interiors]
        if holes:
            cv2.fillPoly(layers[0], holes, 0, shift=4)
    lines = [
        pixels(p)
        for p, label in zip(elements.polylines_m, elements.labels, strict=True)
        if label != MAP_CLASSES.index("ped_crossing")
    ]
    cv2.polylines(layers[1], lines, False, 1, 1, shift=4)
    cv2.fillPoly(layers[2], [pixels(c) for c in elements.crosswalks_m], 1, shift=4)
    return layers
