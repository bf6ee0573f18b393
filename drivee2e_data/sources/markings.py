"""Lane markings and stop lines derived from lane geometry, for maps that give centre lines and
no paint (V2X-Seq's, and so DriveE2E's): a twin without markings shows a camera policy no lanes.

Outside the junction, each side of a lane is painted after what lies beyond it: a lane in the
same direction, a dashed white line; a lane in the opposite direction, a double line in the
colour the map's country uses between opposing traffic (yellow in China and North America,
white in most of Europe); nothing (the road's edge), a solid white line. Junction lanes stay
unpainted. Signal-controlled lanes entering the junction get a stop line across their end
where the map has none. Every derived element is flagged in the map's metadata.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import replace

import numpy as np
import shapely

from drivee2e_data.geometry import wrap_angle
from drivee2e_data.hdmap import (
    IntersectionMap,
    Lane,
    LaneMark,
    LaneType,
    MarkColour,
    MarkPattern,
    StopLine,
    line_heading_at,
)

DASHED_WHITE = LaneMark(MarkPattern.DASHED, MarkColour.WHITE)
SOLID_WHITE = LaneMark(MarkPattern.SOLID, MarkColour.WHITE)
PROBE_BEYOND_M = 0.8  # probes sit this far beyond a lane's boundary
PROBES = 7  # along the middle 70% of a lane
SAME_DIRECTION_RAD = np.deg2rad(60.0)
OPPOSITE_RAD = np.deg2rad(120.0)


def opposing_colour(latitude_deg: float, longitude_deg: float) -> MarkColour:
    """Yellow between opposing traffic in the Americas and East Asia (China, Korea, Japan's
    centre lines are white or yellow; yellow is taken), white elsewhere (Europe)."""
    if -170.0 <= longitude_deg <= -30.0 or 95.0 <= longitude_deg <= 150.0:
        return MarkColour.YELLOW
    return MarkColour.WHITE


def derive_markings(
    intersection_map: IntersectionMap, signal_controlled: Iterable[str] = ()
) -> IntersectionMap:
    """The map with marks on every unpainted side of its non-junction lanes, and stop lines at
    the ends of the `signal_controlled` lanes (ids) that enter the junction and have none."""
    lanes = list(intersection_map.lanes)
    roads = [lane for lane in lanes if lane.lane_type == LaneType.VEHICLE]
    outside = [lane for lane in roads if not lane.is_intersection]
    polygons = [lane.polygon() for lane in outside]
    tree = shapely.STRtree(polygons)
    colour = opposing_colour(
        intersection_map.origin.latitude_deg, intersection_map.origin.longitude_deg
    )
    opposing = LaneMark(MarkPattern.DOUBLE_SOLID, colour)
    painted = []
    for lane in lanes:
        if lane.is_intersection or lane.lane_type != LaneType.VEHICLE:
            painted.append(lane)
            continue
        marks = {}
        for side, current in (("left", lane.left_mark), ("right", lane.right_mark)):
            if current.pattern != MarkPattern.NONE:
                marks[side] = current
                continue
            beyond = _beyond(lane, side, outside, polygons, tree)
            marks[side] = {"same": DASHED_WHITE, "opposite": opposing}.get(beyond, SOLID_WHITE)
        painted.append(replace(lane, left_mark=marks["left"], right_mark=marks["right"]))
    stop_lines = list(intersection_map.stop_lines)
    stopped = {lane_id for stop_line in stop_lines for lane_id in stop_line.lane_ids}
    by_id = {lane.lane_id: lane for lane in painted}
    added = 0
    for lane_id in signal_controlled:
        lane = by_id.get(lane_id)
        if lane is None or lane.is_intersection or lane_id in stopped:
            continue
        if not any(by_id[s].is_intersection for s in lane.successors if s in by_id):
            continue
        line = np.stack([lane.left_boundary_m[-1], lane.right_boundary_m[-1]])
        stop_lines.append(StopLine(f"stop_derived_{lane_id}", line, (lane_id,), derived=True))
        added += 1
    return replace(
        intersection_map,
        lanes=tuple(painted),
        stop_lines=tuple(stop_lines),
        metadata={
            **intersection_map.metadata,
            "markings": "derived from lane geometry (the map has no paint)",
            "derived_stop_lines": added,
        },
    )


def _beyond(
    lane: Lane,
    side: str,
    outside: list[Lane],
    polygons: list[shapely.Geometry],
    tree: shapely.STRtree,
) -> str:
    """What lies past one side of a lane along most of it: 'same', 'opposite' or 'edge'."""
    centre = shapely.LineString(lane.centerline_m[:, :2])
    boundary = lane.left_boundary_m if side == "left" else lane.right_boundary_m
    edge = shapely.LineString(boundary[:, :2])
    votes = {"same": 0, "opposite": 0, "edge": 0}
    for fraction in np.linspace(0.15, 0.85, PROBES):
        middle = centre.interpolate(fraction, normalized=True)
        on_edge = edge.interpolate(edge.project(middle))
        away = np.array([on_edge.x - middle.x, on_edge.y - middle.y])
        norm = float(np.linalg.norm(away))
        if norm < 1e-6:
            continue
        probe = shapely.Point(*(np.array([on_edge.x, on_edge.y]) + PROBE_BEYOND_M * away / norm))
        heading = line_heading_at(centre, middle)
        found = "edge"
        for index in tree.query(probe, predicate="intersects"):
            other = outside[int(index)]
            if other.lane_id == lane.lane_id:
                continue
            line = shapely.LineString(other.centerline_m[:, :2])
            turn = abs(float(wrap_angle(line_heading_at(line, probe) - heading)))
            if turn < SAME_DIRECTION_RAD:
                found = "same"
                break
            if turn > OPPOSITE_RAD:
                found = "opposite"
        votes[found] += 1
    return max(votes, key=lambda k: (votes[k], k != "edge"))
