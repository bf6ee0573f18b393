"""Closed-loop scores: the infractions of one episode, route completion, Driving Score and
Success Rate, after the CARLA Leaderboard 2.0 rules the paper uses (see ../shared/SPEC.md).

Penalties multiply: collision with a pedestrian 0.50, a vehicle 0.60, static layout 0.65, red
light 0.70, stop sign 0.80, scenario timeout 0.70; driving outside route lanes multiplies by
(1 - percent / 100); minimum speed (off by default, as Bench2Drive) by 0.7 + 0.3 * ratio.
Route deviation, agent blocked, route timeout and an agent failure end the route.

Thresholds made for CARLA's kilometre-long routes are scaled to a 10-30 s intersection clip;
each is a named constant below, and docs/closedloop.md lists them. World frame throughout
(the map's local ENU, metres, radians).
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
import shapely
from numpy.typing import NDArray

from drivee2e_data.binding import holding_signals
from drivee2e_data.collision import boxes_collide
from drivee2e_data.geometry import polyline_arclength, wrap_angle
from drivee2e_data.hdmap import IntersectionMap, LaneType, line_heading_at
from drivee2e_data.scenario import AgentClass, SignalState

# CARLA ends a route 30 m off it on kilometre-long routes; an intersection's lanes are 3-4 m wide,
# so two lanes' worth off the route is already elsewhere
ROUTE_DEVIATION_M = 8.0
# the route counts as driven to its end within this distance of it
ROUTE_END_TOLERANCE_M = 1.0
# CARLA: blocked after 180 s below 0.1 m/s. Here: stopped this much longer than the logged
# driver's longest stop in the clip (a clip may hold a 20 s red light)
BLOCKED_SPEED_MPS = 0.1
BLOCKED_MARGIN_S = 6.0
# the route times out at this multiple of the logged duration plus a margin
ROUTE_TIMEOUT_FACTOR = 1.5
ROUTE_TIMEOUT_MARGIN_S = 5.0
# arriving later than the log by more than this (and 20%) is a scenario timeout (penalty 0.70)
SCENARIO_TIMEOUT_MARGIN_S = 2.0
SCENARIO_TIMEOUT_SHARE = 0.2
# a collision is the ego's when the ego moves and the partner is not behind the ego's rear
AT_FAULT_MIN_SPEED_MPS = 0.2
# lane membership: a lane's polygon grown by this, its heading within this of the ego's
LANE_TOLERANCE_M = 0.3
LANE_HEADING_TOLERANCE_RAD = np.deg2rad(60.0)
# driving over a kerb: a wheel's contact point (the box's corners taken in by the inset, at the
# axles) outside the drivable area by more than the tolerance. Mapped kerb lines and logged boxes
# both carry noise of about this size in real data (docs/curation.md, the expert-replay check)
WHEEL_INSET_M = 0.2
OFF_ROAD_TOLERANCE_M = 0.25
# progress is searched this far back and ahead of the last progress (U-turns come back near
# their start; a global nearest point would jump there)
PROGRESS_BACK_M = 5.0
PROGRESS_AHEAD_M = 25.0


class Infraction(enum.Enum):
    COLLISION_PEDESTRIAN = "collision_pedestrian"
    COLLISION_VEHICLE = "collision_vehicle"
    COLLISION_STATIC = "collision_static"
    RED_LIGHT = "red_light"
    STOP_SIGN = "stop_sign"
    SCENARIO_TIMEOUT = "scenario_timeout"
    OUTSIDE_ROUTE_LANES = "outside_route_lanes"
    MIN_SPEED = "min_speed"
    ROUTE_DEVIATION = "route_deviation"
    AGENT_BLOCKED = "agent_blocked"
    ROUTE_TIMEOUT = "route_timeout"
    AGENT_FAILED = "agent_failed"  # the agent crashed, hung or answered garbage


PENALTY: dict[Infraction, float] = {
    Infraction.COLLISION_PEDESTRIAN: 0.50,
    Infraction.COLLISION_VEHICLE: 0.60,
    Infraction.COLLISION_STATIC: 0.65,
    Infraction.RED_LIGHT: 0.70,
    Infraction.STOP_SIGN: 0.80,
    Infraction.SCENARIO_TIMEOUT: 0.70,
}
MIN_SPEED_PENALTY = 0.7
ENDS_ROUTE = frozenset(
    {
        Infraction.ROUTE_DEVIATION,
        Infraction.AGENT_BLOCKED,
        Infraction.ROUTE_TIMEOUT,
        Infraction.AGENT_FAILED,
    }
)
COLLISIONS = frozenset(
    {Infraction.COLLISION_PEDESTRIAN, Infraction.COLLISION_VEHICLE, Infraction.COLLISION_STATIC}
)


@dataclass(frozen=True)
class Event:
    """One infraction at `frame` (10 Hz step of the episode), with the partner's id for
    collisions and the stop line's for red lights."""

    infraction: Infraction
    frame: int
    partner_id: str | None = None
    detail: str = ""


@dataclass(frozen=True)
class Obstacle:
    """Something the ego can hit at one step: an agent (with its class) or a static object."""

    partner_id: str
    agent_class: AgentClass | None  # None: static layout
    centre_xy_m: NDArray[np.float64]
    yaw_rad: float
    length_m: float
    width_m: float


def collision_kind(obstacle: Obstacle) -> Infraction:
    if obstacle.agent_class is None:
        return Infraction.COLLISION_STATIC
    if obstacle.agent_class is AgentClass.PEDESTRIAN:
        return Infraction.COLLISION_PEDESTRIAN
    return Infraction.COLLISION_VEHICLE  # cyclists and riders are vehicles, as in CARLA


def colliding(
    ego_centre_xy_m: NDArray[np.float64],
    ego_yaw_rad: float,
    ego_size_m: tuple[float, float],
    ego_speed_mps: float,
    obstacles: Sequence[Obstacle],
) -> list[Obstacle]:
    """The obstacles whose box overlaps the ego's box (`collision.boxes_collide`, the definition
    staging shares) and whose collision is the ego's fault:
    not while the ego stands still, not when the partner's centre is behind the ego's rear
    bumper (a replayed agent cannot brake for an ego that lags its logged self)."""
    if not obstacles:
        return []
    centres = np.array([o.centre_xy_m for o in obstacles])
    hit = boxes_collide(
        np.asarray(ego_centre_xy_m, np.float64),
        np.float64(ego_yaw_rad),
        np.asarray(ego_size_m, np.float64),
        centres,
        np.array([o.yaw_rad for o in obstacles]),
        np.array([(o.length_m, o.width_m) for o in obstacles]),
    )
    if not hit.any() or ego_speed_mps < AT_FAULT_MIN_SPEED_MPS:
        return []
    along = (centres - ego_centre_xy_m) @ np.array([np.cos(ego_yaw_rad), np.sin(ego_yaw_rad)])
    behind = along < -0.5 * ego_size_m[0]
    return [o for o, h, b in zip(obstacles, hit, behind, strict=True) if h and not b]


class RouteProgress:
    """Progress of the ego along its route (a polyline `(N, 2)` in the world): arclength of the
    nearest route point in a window around the last progress, and the distance to it."""

    def __init__(self, route_xy_m: NDArray[np.float64], spacing_m: float = 0.25) -> None:
        points = _drop_repeats(np.asarray(route_xy_m, np.float64))
        s = polyline_arclength(points)
        self.length_m = float(s[-1])
        samples = np.arange(0.0, self.length_m + spacing_m, spacing_m).clip(max=self.length_m)
        self.points_m = np.stack([np.interp(samples, s, points[:, d]) for d in range(2)], -1)
        self.s_m = samples
        self.progress_m = 0.0

    def update(self, xy_m: NDArray[np.float64]) -> tuple[float, float]:
        """(progress in metres, distance to the route) after the ego reached `xy_m`."""
        window = (self.s_m >= self.progress_m - PROGRESS_BACK_M) & (
            self.s_m <= self.progress_m + PROGRESS_AHEAD_M
        )
        candidates = np.flatnonzero(window)
        distances = np.hypot(*(self.points_m[candidates] - xy_m).T)
        best = candidates[int(np.argmin(distances))]
        self.progress_m = max(self.progress_m, float(self.s_m[best]))
        return self.progress_m, float(distances.min())

    @property
    def completion_percent(self) -> float:
        if self.length_m <= ROUTE_END_TOLERANCE_M:
            return 100.0
        if self.progress_m >= self.length_m - ROUTE_END_TOLERANCE_M:
            return 100.0
        return 100.0 * self.progress_m / self.length_m


def _drop_repeats(points: NDArray[np.float64], min_step_m: float = 0.05) -> NDArray[np.float64]:
    kept = [points[0]]
    for point in points[1:]:
        if np.hypot(*(point - kept[-1])) >= min_step_m:
            kept.append(point)
    if len(kept) == 1:
        kept.append(points[-1] + np.array([1e-3, 0.0]))
    return np.array(kept)


@dataclass(frozen=True)
class _StopLane:
    """A lane a stop line crosses, with the signals that may hold it: the route's own movement
    when the route goes through this lane, else every movement out of it."""

    area: shapely.Geometry
    centre: shapely.LineString
    signal_ids: tuple[str, ...]


@dataclass(frozen=True)
class _StopLine:
    stop_line_id: str
    line: shapely.LineString
    lanes: tuple[_StopLane, ...]


class MapRules:
    """The map's rules for one ego: where it may drive (drivable area, lanes by direction,
    junctions) and which signals hold it at which stop line. Signals sit on a lane or on the
    junction lanes (movements) after it; with `route_lane_ids`, a stop line on the route answers
    to the route's movement."""

    def __init__(
        self, intersection_map: IntersectionMap, route_lane_ids: Sequence[str] = ()
    ) -> None:
        self.drivable = intersection_map.drivable_union()
        shapely.prepare(self.drivable)
        lanes = [lane for lane in intersection_map.lanes if lane.lane_type is LaneType.VEHICLE]
        self.lane_polygons = [lane.polygon().buffer(LANE_TOLERANCE_M) for lane in lanes]
        self.lane_lines = [shapely.LineString(lane.centerline_m[:, :2]) for lane in lanes]
        self.lane_in_junction = [lane.is_intersection for lane in lanes]
        self.junctions = junction_areas(
            [
                p
                for p, inside in zip(self.lane_polygons, self.lane_in_junction, strict=True)
                if inside
            ]
        )
        shapely.prepare(self.junctions)
        self.lane_tree = shapely.STRtree(self.lane_polygons)
        by_id = {lane.lane_id: k for k, lane in enumerate(lanes)}
        route = list(route_lane_ids)
        stop_lines = []
        for stop in intersection_map.stop_lines:
            controlled = []
            for lane_id in stop.lane_ids:
                if lane_id not in by_id:
                    continue
                lane = lanes[by_id[lane_id]]
                signals = holding_signals(lane, lanes, by_id, route)
                if signals:
                    k = by_id[lane_id]
                    controlled.append(_StopLane(self.lane_polygons[k], self.lane_lines[k], signals))
            if controlled:
                line = shapely.LineString(stop.line_m[:, :2])
                stop_lines.append(_StopLine(stop.stop_line_id, line, tuple(controlled)))
        self.stop_lines = tuple(stop_lines)
        self.static = [
            Obstacle(o.obstacle_id, None, o.position_m[:2], o.yaw_rad, o.size_m[0], o.size_m[1])
            for o in intersection_map.static_obstacles
        ]

    def wheels_off_road(self, wheels_xy_m: NDArray[np.float64]) -> bool:
        """Whether any wheel `(K, 2)` (world) stands outside the drivable area by more than
        `OFF_ROAD_TOLERANCE_M`: on a kerb, a sidewalk or beyond."""
        wheels = np.asarray(wheels_xy_m, np.float64).reshape(-1, 2)
        outside = ~shapely.contains_xy(self.drivable, wheels[:, 0], wheels[:, 1])
        if not outside.any():
            return False
        points = shapely.points(wheels[outside])
        return bool((shapely.distance(self.drivable, points) > OFF_ROAD_TOLERANCE_M).any())

    def lane_status(
        self,
        xy_m: NDArray[np.float64],
        yaw_rad: float,
        wheels_xy_m: NDArray[np.float64] | None = None,
    ) -> str:
        """'off_road' with the centre `xy_m` outside the drivable area or a wheel over its edge
        (`wheels_off_road`); 'junction' on a junction lane or between them, inside a junction's
        hull (not checked for direction, as CARLA does not); 'lane' in a lane heading the ego's
        way; 'wrong_lane'."""
        point = shapely.Point(float(xy_m[0]), float(xy_m[1]))
        if not self.drivable.contains(point):
            return "off_road"
        if wheels_xy_m is not None and self.wheels_off_road(wheels_xy_m):
            return "off_road"
        same_direction = False
        for index in self.lane_tree.query(point, predicate="intersects"):
            if self.lane_in_junction[index]:
                return "junction"
            if (
                abs(float(wrap_angle(line_heading_at(self.lane_lines[index], point) - yaw_rad)))
                <= LANE_HEADING_TOLERANCE_RAD
            ):
                same_direction = True  # fmt: skip
        if same_direction:
            return "lane"
        # between a junction's lanes (a U-turn the map has no lane for) is the junction still
        return "junction" if self.junctions.contains(point) else "wrong_lane"

    def red_lights_crossed(
        self,
        front_before_m: NDArray[np.float64],
        front_after_m: NDArray[np.float64],
        yaw_rad: float,
        signal_states: dict[str, SignalState],
    ) -> list[str]:
        """Stop lines the front bumper crossed between two steps, driving along one of the
        line's lanes, while that lane's signal was red."""
        if np.hypot(*(front_after_m - front_before_m)) < 1e-6:
            return []
        path = shapely.LineString([front_before_m, front_after_m])
        crossed = []
        for stop in self.stop_lines:
            if not path.intersects(stop.line):
                continue
            for lane in stop.lanes:
                heading = line_heading_at(lane.centre, shapely.Point(*front_before_m))
                aligned = abs(float(wrap_angle(heading - yaw_rad))) <= LANE_HEADING_TOLERANCE_RAD
                red = all(signal_states.get(s) is SignalState.RED for s in lane.signal_ids)
                if aligned and red and lane.area.intersects(path):
                    crossed.append(stop.stop_line_id)
                    break
        return crossed


def junction_areas(junction_lanes: Sequence[shapely.Geometry]) -> shapely.Geometry:
    """The junctions' areas: the convex hull of each group of touching junction lane polygons
    (CARLA checks no lane inside a junction's bounds, and neither does this)."""
    if not junction_lanes:
        return shapely.Polygon()
    merged = shapely.union_all(junction_lanes)
    return shapely.union_all([part.convex_hull for part in getattr(merged, "geoms", [merged])])


def wheel_points(
    rear_axle_xy_m: NDArray[np.float64], yaw_rad: float, wheelbase_m: float, width_m: float
) -> NDArray[np.float64]:
    """(4, 2) the contact points of a car's wheels in the world: the rear axle at
    `rear_axle_xy_m`, the front axle `wheelbase_m` ahead along `yaw_rad`, each wheel
    `WHEEL_INSET_M` in from the box's side."""
    forward = np.array([np.cos(yaw_rad), np.sin(yaw_rad)])
    left = np.array([-forward[1], forward[0]])
    half_track = max(0.5 * width_m - WHEEL_INSET_M, 0.0)
    axles = np.asarray(rear_axle_xy_m, np.float64) + np.outer([0.0, wheelbase_m], forward)
    return np.concatenate([axles + half_track * left, axles - half_track * left])


def longest_stop_s(speed_mps: NDArray[np.float64], step_s: float = 0.1) -> float:
    """The longest run of steps below the blocked speed, in seconds."""
    longest = run = 0
    for stopped in np.asarray(speed_mps) < BLOCKED_SPEED_MPS:
        run = run + 1 if stopped else 0
        longest = max(longest, run)
    return longest * step_s


@dataclass(frozen=True)
class EpisodeScore:
    """The score of one route: completion (percent), the penalty product, DS = RC x penalty,
    success, and the events behind them."""

    route_completion: float
    penalty: float
    driving_score: float
    success: bool
    outside_lanes_percent: float
    events: tuple[Event, ...] = field(default_factory=tuple)
    status: str = "completed"  # or the infraction that ended the route

    def count(self, infraction: Infraction) -> int:
        return sum(e.infraction is infraction for e in self.events)


def score(
    route_completion: float,
    events: Iterable[Event],
    outside_lanes_percent: float,
    min_speed_ratio: float | None = None,
) -> EpisodeScore:
    """The episode's score from its events. `min_speed_ratio` (the ego's mean speed over the
    logged driver's, when the minimum-speed rule is on) adds its penalty when below 1."""
    events = tuple(events)
    penalty = 1.0
    for event in events:
        penalty *= PENALTY.get(event.infraction, 1.0)
    outside = float(np.clip(outside_lanes_percent, 0.0, 100.0))
    penalty *= 1.0 - outside / 100.0
    if min_speed_ratio is not None and min_speed_ratio < 1.0:
        penalty *= MIN_SPEED_PENALTY + (1.0 - MIN_SPEED_PENALTY) * max(min_speed_ratio, 0.0)
    ended = [e for e in events if e.infraction in ENDS_ROUTE]
    completion = float(np.clip(route_completion, 0.0, 100.0))
    success = (
        completion >= 100.0
        and not ended
        and outside == 0.0
        and not any(e.infraction in PENALTY for e in events)
    )
    return EpisodeScore(
        route_completion=completion,
        penalty=penalty,
        driving_score=completion * penalty,
        success=success,
        outside_lanes_percent=outside,
        events=events,
        status=ended[0].infraction.value if ended else "completed",
    )
