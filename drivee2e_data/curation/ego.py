"""Ego choice: which vehicle of a clip the benchmark drives.

A candidate is a motor vehicle (car, van, truck, bus) valid in every frame of the clip, inside
the mapped area throughout, that moves, and whose drive the map's lanes carry (every moving
frame within `LANE_REACH_M` of a lane centre line). Across a dataset the chosen egos balance
behaviour categories: each clip takes the candidate whose category is rarest so far.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable

import numpy as np
import shapely

from drivee2e_data.geometry import polyline_arclength, resample_polyline
from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.scenario import BehaviorCategory, Route, Scenario, SubScenario, Track

MAP_REACH_M = 2.0  # a candidate never leaves the drivable area by more than this
LANE_REACH_M = 2.5  # ...and always drives this close to some lane centre line
MIN_TRAVEL_M = 5.0  # a vehicle that moves less than this over the clip shows no behaviour


def moves(track: Track) -> bool:
    """Whether a track travels at least `MIN_TRAVEL_M` over its valid frames."""
    xy = track.xy_m[track.valid]
    return bool(
        len(xy)
        and (
            np.linalg.norm(xy[-1] - xy[0]) >= MIN_TRAVEL_M
            or np.ptp(xy, axis=0).max() >= MIN_TRAVEL_M
        )
    )


def is_candidate(track: Track, intersection_map: IntersectionMap) -> bool:
    if not track.agent_class.is_motor_vehicle or not track.valid.all() or not moves(track):
        return False
    points = shapely.points(track.x_m, track.y_m)
    road = intersection_map.drivable_union()
    if shapely.distance(road, points).max() > MAP_REACH_M:
        return False
    lines = shapely.MultiLineString([lane.centerline_m[:, :2] for lane in intersection_map.lanes])
    moving = track.speed_mps > 0.5
    return bool(np.all(shapely.distance(lines, points[moving]) <= LANE_REACH_M))


def candidates(scenario: Scenario, intersection_map: IntersectionMap) -> list[str]:
    return [t.track_id for t in scenario.tracks if is_candidate(t, intersection_map)]


def choose(
    options: dict[str, SubScenario], counts: Counter[BehaviorCategory]
) -> tuple[str, SubScenario] | None:
    """The candidate whose category is rarest in `counts` (ties: the first in id order)."""
    if not options:
        return None
    return min(sorted(options.items()), key=lambda item: counts[item[1].category])


def choose_ego(
    scenario: Scenario,
    intersection_map: IntersectionMap,
    counts: Counter[BehaviorCategory],
    labeller: Callable[[Scenario, IntersectionMap, str], SubScenario],
) -> tuple[str, SubScenario] | None:
    """Label every candidate and take the one that best balances `counts`."""
    options = {
        track_id: labeller(scenario, intersection_map, track_id)
        for track_id in candidates(scenario, intersection_map)
    }
    return choose(options, counts)


def route_of(track: Track, lane_ids: list[str]) -> Route:
    """The route of a chosen ego: the lanes it drives and its path resampled every metre."""
    xy = track.xy_m[track.valid]
    steps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    points = xy[np.concatenate([[True], steps > 1e-6])]
    if len(points) < 2 or polyline_arclength(points)[-1] < 1.0:
        points = np.stack([xy[0], xy[-1] + np.array([1e-3, 0.0])])
    else:
        points = resample_polyline(points, 1.0)
    return Route(tuple(lane_ids), points)
