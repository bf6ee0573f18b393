"""Which signal binds the ego, frame by frame: the one at the next signal-controlled stop line
ahead of its front bumper along its route (none once it has crossed the last one).

A route's stops come from the map: each stop line across one of the route's lanes, held by
that lane's signal or, where the signal sits on the junction lane beyond the line (most maps),
by the signal of the next route lane (`holding_signals`, which the closed-loop red-light rule
reads too). The ego's progress is its front bumper projected on the route's centreline (its
lanes' centrelines joined in order); a stop is passed once the front is past the point where
the stop line meets that centreline.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from numpy.typing import NDArray

from drivee2e_data.hdmap import IntersectionMap, Lane


def holding_signals(
    lane: Lane, lanes: Sequence[Lane], by_id: dict[str, int], route: Sequence[str]
) -> tuple[str, ...]:
    """The signals that hold traffic at a stop line across `lane`: the lane's own signal, else
    those of its successors (only the next route lane's, where `route` names it)."""
    if lane.signal_id is not None:
        return (lane.signal_id,)
    successors = [lanes[by_id[s]] for s in lane.successors if s in by_id]
    route = list(route)
    if lane.lane_id in route and route.index(lane.lane_id) + 1 < len(route):
        following = route[route.index(lane.lane_id) + 1]
        successors = [m for m in successors if m.lane_id == following] or successors
    return tuple(sorted({m.signal_id for m in successors if m.signal_id is not None}))


@dataclass(frozen=True)
class RouteStop:
    """A signal-controlled stop line on the route: where it meets the route's centreline (metres
    along it) and the signals that hold it (the first binds the ego)."""

    stop_line_id: str
    along_m: float
    signal_ids: tuple[str, ...]


def route_centreline(intersection_map: IntersectionMap, route_lane_ids: Sequence[str]):
    """The route's lanes' centrelines joined in route order (a shapely LineString), or None
    where no route lane is on the map."""
    by_id = {lane.lane_id: lane for lane in intersection_map.lanes}
    points: list[NDArray[np.float64]] = []
    for lane_id in route_lane_ids:
        lane = by_id.get(lane_id)
        if lane is None:
            continue
        centre = lane.centerline_m[:, :2]
        if points and np.allclose(points[-1][-1], centre[0], atol=1e-6):
            centre = centre[1:]
        points.append(centre)
    if not points:
        return None
    joined = np.concatenate(points)
    keep = np.concatenate(([True], np.any(np.diff(joined, axis=0) != 0.0, axis=1)))
    joined = joined[keep]
    return shapely.LineString(joined) if len(joined) >= 2 else None


def route_stops(
    intersection_map: IntersectionMap, route_lane_ids: Sequence[str], path=None
) -> tuple[RouteStop, ...]:
    """The route's signal-controlled stop lines, nearest the route's start first (`path`: the
    route's centreline where the caller has made it, `route_centreline`)."""
    path = route_centreline(intersection_map, route_lane_ids) if path is None else path
    if path is None:
        return ()
    lanes = list(intersection_map.lanes)
    by_id = {lane.lane_id: k for k, lane in enumerate(lanes)}
    route = list(route_lane_ids)
    stops = []
    for stop in intersection_map.stop_lines:
        on_route = [lane_id for lane_id in stop.lane_ids if lane_id in route and lane_id in by_id]
        if not on_route:
            continue
        signals = holding_signals(lanes[by_id[on_route[0]]], lanes, by_id, route)
        if not signals:
            continue
        line = shapely.LineString(stop.line_m[:, :2])
        meeting = path.intersection(line)
        if meeting.is_empty:  # a line that stops short of the centreline: its nearest point
            meeting = shapely.Point(shapely.shortest_line(path, line).coords[0])
        along = shapely.line_locate_point(path, shapely.points(shapely.get_coordinates(meeting)))
        stops.append(RouteStop(stop.stop_line_id, float(along.min()), signals))
    return tuple(sorted(stops, key=lambda s: (s.along_m, s.stop_line_id)))


def front_bumper(
    xy_m: NDArray[np.float64], yaw_rad: NDArray[np.float64], length_m: float | NDArray[np.float64]
) -> NDArray[np.float64]:
    """`(F, 2)` the middle of the front of a box `length_m` long (one length, or one a frame
    `(F,)`) centred at `xy_m` `(F, 2)`, heading `yaw_rad` `(F,)`."""
    yaw = np.asarray(yaw_rad, np.float64)
    direction = np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)
    length = np.asarray(length_m, np.float64).reshape(-1, 1)
    return np.asarray(xy_m, np.float64).reshape(-1, 2) + 0.5 * length * direction


def binding_signals(
    intersection_map: IntersectionMap,
    route_lane_ids: Sequence[str],
    front_xy_m: NDArray[np.float64],
) -> list[str | None]:
    """Per frame, the signal that binds an ego whose front bumper is at `front_xy_m` `(F, 2)`:
    the first holder of the first route stop still ahead; None where none is ahead (passed the
    last, or a route with no signal-controlled stop line)."""
    path = route_centreline(intersection_map, route_lane_ids)
    stops = route_stops(intersection_map, route_lane_ids, path)
    front = np.asarray(front_xy_m, np.float64).reshape(-1, 2)
    if not stops:
        return [None] * len(front)
    along = shapely.line_locate_point(path, shapely.points(front))
    result: list[str | None] = []
    for position in along:
        ahead = next((stop for stop in stops if stop.along_m > position), None)
        result.append(None if ahead is None else ahead.signal_ids[0])
    return result
