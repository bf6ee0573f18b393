"""Procedural intersection layouts: arms, lanes, connectors, crosswalks, kerbside, signals.

An intersection is a star of 3 or 4 straight arms meeting at the origin, with right-hand traffic.
Arm i points outward along `u_i = (cos a_i, sin a_i)`; `n_i` is `u_i` turned left. Incoming lanes
lie on the +n side (lane 0 next to the centre line), outgoing lanes on the -n side.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from numpy.typing import NDArray

from drivee2e_data.collision import EXPERT_TRACKING_MARGIN_M
from drivee2e_data.ego_limits import MAX_STEER_RAD, REAR_AXLE_SHARE, WHEELBASE_SHARE
from drivee2e_data.geometry import box_corners_2d, cubic_bezier, resample_polyline, wrap_angle
from drivee2e_data.hdmap import (
    Area,
    Building,
    Crosswalk,
    GeoOrigin,
    IntersectionMap,
    Lane,
    LaneMark,
    MarkColour,
    MarkPattern,
    SignalHead,
    SignalKind,
    StopLine,
    Tree,
    TurnDirection,
)
from drivee2e_data.scenario import AgentClass
from drivee2e_data.sources.common import TYPICAL_SIZE_M

LANE_WIDTH_M = 3.5
SIDEWALK_WIDTH_M = 4.0
KERB_HEIGHT_M = 0.15
CROSSWALK_WIDTH_M = 4.0
STOP_LINE_GAP_M = 1.0  # stop line sits this far before the crosswalk
ARM_LENGTH_M = 200.0
CONNECTOR_SPACING_M = 0.5
SPEED_LIMIT_MPS = 50 / 3.6
# a crosswalk's pedestrian signal stands this far behind the kerb, behind the people waiting
# there (`population.KERB_WAIT_M`: their boxes reach 1.0 m back)
PEDESTRIAN_SIGNAL_SETBACK_M = 1.6
# vehicles are drawn up to this share of their class's typical size (`population.sized`)
MAX_SIZE_SCALE = 1.08
# The junction's kerbs are drawn around the swept path of its design vehicle on every turn and
# straight, plus a clearance, as road designers draw corner radii around a design vehicle's
# turning path: the largest ego (a van), so an ego's logged drive never crosses a kerb.
DESIGN_VEHICLE_M = tuple(MAX_SIZE_SCALE * v for v in TYPICAL_SIZE_M[AgentClass.VAN][:2])
TURN_KERB_CLEARANCE_M = 0.3
# U-turns are made by cars only (`population`), on a loop the largest car follows with its
# wheels at no more than this share of their lock, its swept box this far inside the kerbs
# (the closed-loop expert's tracking margin: pedestrians wait at the kerb); a U-turn that no
# loop fits is not offered on that arm.
U_TURN_VEHICLE_M = tuple(MAX_SIZE_SCALE * v for v in TYPICAL_SIZE_M[AgentClass.CAR][:2])
U_TURN_STEER_SHARE = 0.85
U_TURN_KERB_CLEARANCE_M = EXPERT_TRACKING_MARGIN_M
U_TURN_RADIUS_STEPS_M = (0.0, 0.5, 1.0, 1.5, 2.0, 3.0)  # added to the smallest radius
U_TURN_DEPTHS_M = (0.0, 2.0, 4.0, 6.0, 8.0)  # extra depth of the loop into the junction


def u_turn_min_radius_m(length_m: float = U_TURN_VEHICLE_M[0]) -> float:
    """The smallest loop radius (m, of the box centre's path) a car `length_m` long follows
    with its wheels at `U_TURN_STEER_SHARE` of their lock: its rear axle, `REAR_AXLE_SHARE`
    lengths behind the centre, turns on the kinematic bicycle's radius."""
    wheelbase = WHEELBASE_SHARE * length_m
    rear_radius = wheelbase / np.tan(U_TURN_STEER_SHARE * MAX_STEER_RAD)
    return float(np.hypot(rear_radius, REAR_AXLE_SHARE * length_m))


@dataclass(frozen=True)
class Arm:
    index: int
    angle_rad: float
    lanes_in: int
    lanes_out: int
    junction_edge_m: float  # distance from the centre where the arm's road leaves the junction

    @property
    def u(self) -> NDArray[np.float64]:
        return np.array([np.cos(self.angle_rad), np.sin(self.angle_rad)])

    @property
    def n(self) -> NDArray[np.float64]:
        return np.array([-np.sin(self.angle_rad), np.cos(self.angle_rad)])

    @property
    def stop_m(self) -> float:
        """Distance from the centre of the stop line (where approach lanes end)."""
        return self.junction_edge_m + CROSSWALK_WIDTH_M + STOP_LINE_GAP_M

    def point(self, along_m: float, lateral_m: float) -> NDArray[np.float64]:
        return along_m * self.u + lateral_m * self.n

    def incoming_offset(self, lane: int) -> float:
        return (lane + 0.5) * LANE_WIDTH_M

    def outgoing_offset(self, lane: int) -> float:
        return -(lane + 0.5) * LANE_WIDTH_M


@dataclass(frozen=True)
class Movement:
    """A way through the junction: from an incoming lane to an outgoing lane.

    `lane_id` is the connector lane in the map, or None for an abnormal movement that the map
    does not carry (a U-turn from a lane that forbids it). `signal_id` controls the movement.
    """

    movement_id: str
    from_arm: int
    from_lane: str
    to_arm: int
    to_lane: str
    turn: TurnDirection
    signal_id: str
    path_m: NDArray[np.float64]  # (N, 2) from the stop line to the start of the outgoing lane
    lane_id: str | None
    abnormal: bool = False


@dataclass(frozen=True)
class Layout:
    """A generated intersection: its map plus the movement table the traffic model drives on."""

    intersection_map: IntersectionMap
    arms: tuple[Arm, ...]
    movements: tuple[Movement, ...]
    axes: tuple[tuple[int, ...], ...]  # groups of arms that share a green phase
    protected_left: tuple[bool, ...]  # per axis

    def movement(self, movement_id: str) -> Movement:
        for candidate in self.movements:
            if candidate.movement_id == movement_id:
                return candidate
        raise KeyError(movement_id)

    def axis_of(self, arm: int) -> int:
        return next(k for k, axis in enumerate(self.axes) if arm in axis)


def incoming_lane_id(arm: int, lane: int) -> str:
    return f"a{arm}_in{lane}"


def outgoing_lane_id(arm: int, lane: int) -> str:
    return f"a{arm}_out{lane}"


def through_signal_id(arm: int) -> str:
    return f"sig_a{arm}_through"


def left_signal_id(arm: int) -> str:
    return f"sig_a{arm}_left"


def pedestrian_signal_id(arm: int) -> str:
    return f"ped_a{arm}"


def generate_layout(map_id: str, rng: np.random.Generator) -> Layout:
    """A random 3- or 4-way intersection with 1-3 lanes per direction and skewed arms."""
    num_arms = int(rng.choice([3, 4], p=[0.35, 0.65]))
    base = np.array([0.0, 90.0, 180.0, 270.0])
    if num_arms == 3:
        base = np.delete(base, int(rng.integers(4)))
    angles = np.deg2rad(base + rng.uniform(-15.0, 15.0, size=num_arms) + rng.uniform(0, 360))
    lanes = [int(rng.choice([1, 2, 3], p=[0.3, 0.45, 0.25])) for _ in range(num_arms)]
    edges = _junction_edges(angles, lanes)
    arms = tuple(
        Arm(i, float(wrap_angle(a)), lanes[i], lanes[i], edges[i]) for i, a in enumerate(angles)
    )
    axes = _axes(arms)
    protected_axis = int(rng.integers(len(axes)))
    protected_left = tuple(k == protected_axis for k in range(len(axes)))
    movements = _movements(arms, axes, protected_left)
    road = _road_polygon(arms, movements)
    movements = (*movements, *_u_turns(arms, axes, protected_left, road))
    origin = GeoOrigin(
        latitude_deg=float(39.75 + rng.uniform(-0.1, 0.1)),
        longitude_deg=float(116.5 + rng.uniform(-0.1, 0.1)),
        altitude_m=float(rng.uniform(30, 60)),
    )
    intersection_map = _build_map(map_id, origin, arms, axes, protected_left, movements, road, rng)
    return Layout(intersection_map, arms, movements, axes, protected_left)


def _junction_edges(angles: NDArray[np.float64], lanes: list[int]) -> list[float]:
    """Distance from the centre at which each arm's road (with sidewalks) clears its neighbours."""
    order = np.argsort(angles % (2 * np.pi))
    edges = [6.0] * len(angles)
    for k in range(len(order)):
        i, j = int(order[k]), int(order[(k + 1) % len(order)])
        gap = (angles[j] - angles[i]) % (2 * np.pi)
        if gap > np.deg2rad(150):
            continue  # the kerbs diverge: no corner between these arms
        half_i = lanes[i] * LANE_WIDTH_M + SIDEWALK_WIDTH_M
        half_j = lanes[j] * LANE_WIDTH_M + SIDEWALK_WIDTH_M
        u_i = np.array([np.cos(angles[i]), np.sin(angles[i])])
        u_j = np.array([np.cos(angles[j]), np.sin(angles[j])])
        n_i = np.array([-u_i[1], u_i[0]])
        n_j = np.array([-u_j[1], u_j[0]])
        # Corner point X with X.n_i = half_i (left kerb of arm i) and X.(-n_j) = half_j.
        corner = np.linalg.solve(np.stack([n_i, -n_j]), np.array([half_i, half_j]))
        edges[i] = max(edges[i], float(corner @ u_i) + 2.0)
        edges[j] = max(edges[j], float(corner @ u_j) + 2.0)
    return edges


def _axes(arms: tuple[Arm, ...]) -> tuple[tuple[int, ...], ...]:
    """Pairs of roughly opposite arms share a phase; a 3-way's stem has a phase of its own."""
    if len(arms) == 4:
        order = sorted(range(4), key=lambda i: arms[i].angle_rad % (2 * np.pi))
        return ((order[0], order[2]), (order[1], order[3]))
    best = max(
        ((i, j) for i in range(3) for j in range(i + 1, 3)),
        key=lambda p: abs(wrap_angle(arms[p[0]].angle_rad - arms[p[1]].angle_rad)),
    )
    stem = next(i for i in range(3) if i not in best)
    return (best, (stem,))


def turn_between(from_arm: Arm, to_arm: Arm) -> TurnDirection:
    """The turn of a movement entering from `from_arm` and leaving by `to_arm`."""
    if from_arm.index == to_arm.index:
        return TurnDirection.U_TURN
    delta = float(wrap_angle(to_arm.angle_rad - (from_arm.angle_rad + np.pi)))
    if abs(delta) < np.deg2rad(40):
        return TurnDirection.STRAIGHT
    return TurnDirection.LEFT if delta > 0 else TurnDirection.RIGHT


def _lane_permissions(arm: Arm, turns: set[TurnDirection]) -> list[set[TurnDirection]]:
    """Which turns each incoming lane (0 = leftmost) allows."""
    left, straight, right = TurnDirection.LEFT, TurnDirection.STRAIGHT, TurnDirection.RIGHT
    count = arm.lanes_in
    if count == 1:
        allowed = [set(turns)]
    elif count == 2:
        allowed = [{left, straight}, {straight, right}]
    else:
        allowed = [{left}] + [{straight}] * (count - 2) + [{straight, right}]
    result = [a & turns for a in allowed]
    # A lane left with nothing (no straight at a T) takes the nearest available turn.
    for lane, allowed_turns in enumerate(result):
        if not allowed_turns:
            result[lane] = (
                {left} if (left in turns and lane < count / 2) else ({right} & turns or turns)
            )
    return result


def _movements(
    arms: tuple[Arm, ...], axes: tuple[tuple[int, ...], ...], protected_left: tuple[bool, ...]
) -> tuple[Movement, ...]:
    movements: list[Movement] = []
    for arm in arms:
        targets = {turn_between(arm, other): other for other in arms if other.index != arm.index}
        permissions = _lane_permissions(arm, set(targets))
        axis = next(k for k, group in enumerate(axes) if arm.index in group)
        left_signal = (
            left_signal_id(arm.index) if protected_left[axis] else through_signal_id(arm.index)
        )
        for lane, allowed in enumerate(permissions):
            for turn in sorted(allowed, key=lambda t: t.value):
                target = targets[turn]
                lanes_with_turn = [k for k, a in enumerate(permissions) if turn in a]
                rank = lanes_with_turn.index(lane)
                # right turns keep to the kerb; others fill exit lanes from the left
                last = target.lanes_out - 1
                out_lane = last if turn == TurnDirection.RIGHT else min(rank, last)
                signal = left_signal if turn == TurnDirection.LEFT else through_signal_id(arm.index)
                movements.append(_movement(arm, lane, target, out_lane, turn, signal))
    return tuple(movements)


def _u_turns(
    arms: tuple[Arm, ...],
    axes: tuple[tuple[int, ...], ...],
    protected_left: tuple[bool, ...],
    road: shapely.Polygon,
) -> tuple[Movement, ...]:
    """U-turns where a loop fits the junction (`_fitting_u_turn`): from each arm's leftmost
    lane on its left-turn signal; from its rightmost lane too when there are two or more, an
    abnormal movement that the map does not carry."""
    inside = road.buffer(-U_TURN_KERB_CLEARANCE_M)
    shapely.prepare(inside)
    movements = []
    for arm in arms:
        axis = next(k for k, group in enumerate(axes) if arm.index in group)
        left_signal = (
            left_signal_id(arm.index) if protected_left[axis] else through_signal_id(arm.index)
        )
        lanes = [(0, left_signal, False)]
        if arm.lanes_in > 1:
            lanes.append((arm.lanes_in - 1, through_signal_id(arm.index), True))
        for lane, signal, abnormal in lanes:
            movement = _fitting_u_turn(arm, lane, signal, abnormal, inside)
            if movement is not None:
                movements.append(movement)
    return tuple(movements)


def _fitting_u_turn(
    arm: Arm, lane: int, signal_id: str, abnormal: bool, inside: shapely.Geometry
) -> Movement | None:
    """The first U-turn from `lane` whose loop the largest car sweeps inside the kerbs less the
    clearance (`inside`): into the outermost outgoing lane first, the smallest radius first,
    the loop as shallow as it fits."""
    smallest = u_turn_min_radius_m()
    for out_lane in range(arm.lanes_out - 1, -1, -1):
        for extra in U_TURN_RADIUS_STEPS_M:
            for depth in U_TURN_DEPTHS_M:
                movement = _movement(
                    arm, lane, arm, out_lane, TurnDirection.U_TURN, signal_id, abnormal,
                    u_turn=(smallest + extra, depth),
                )  # fmt: skip
                if sweeps_inside(movement.path_m, U_TURN_VEHICLE_M, inside):
                    return movement
    return None


def swept_boxes(path_m: NDArray[np.float64], size_m: tuple[float, float]) -> NDArray[np.float64]:
    """(N, 4, 2) the boxes of a vehicle `size_m` (length, width) centred on each point of
    `path_m` (N, 2), turned along the path, as the traffic simulation moves it."""
    heading = np.arctan2(np.gradient(path_m[:, 1]), np.gradient(path_m[:, 0]))
    count = len(path_m)
    return box_corners_2d(path_m, heading, np.full(count, size_m[0]), np.full(count, size_m[1]))


def sweeps_inside(
    path_m: NDArray[np.float64], size_m: tuple[float, float], area: shapely.Geometry
) -> bool:
    """Whether every box along `path_m` lies inside `area` (its outline sampled every 0.25 m,
    so a kerb corner poking between two corners is seen)."""
    boxes = swept_boxes(path_m, size_m)
    edges = np.roll(boxes, -1, axis=1) - boxes
    share = np.linspace(0.0, 1.0, int(np.ceil(max(size_m) / 0.25)), endpoint=False)
    points = boxes[:, :, None, :] + share[None, None, :, None] * edges[:, :, None, :]
    points = points.reshape(-1, 2)
    return bool(shapely.contains_xy(area, points[:, 0], points[:, 1]).all())


def _movement(
    arm: Arm,
    lane: int,
    target: Arm,
    out_lane: int,
    turn: TurnDirection,
    signal_id: str,
    abnormal: bool = False,
    u_turn: tuple[float, float] = (0.0, 0.0),
) -> Movement:
    """The movement from `arm`'s incoming `lane` to `target`'s outgoing `out_lane`; a U-turn's
    loop has the radius and extra depth `u_turn` (m)."""
    start = arm.point(arm.stop_m, arm.incoming_offset(lane))
    end = target.point(target.stop_m, target.outgoing_offset(out_lane))
    heading_in, heading_out = -arm.u, target.u
    if turn == TurnDirection.U_TURN:
        path = _u_turn_path(arm, start, end, *u_turn)
    else:
        reach = 0.4 * float(np.linalg.norm(end - start))
        path = cubic_bezier(start, start + reach * heading_in, end - reach * heading_out, end, 200)
    path = resample_polyline(path, CONNECTOR_SPACING_M)
    from_lane, to_lane = incoming_lane_id(arm.index, lane), outgoing_lane_id(target.index, out_lane)
    movement_id = f"{from_lane}__{to_lane}" + ("__abnormal" if abnormal else "")
    return Movement(
        movement_id=movement_id,
        from_arm=arm.index,
        from_lane=from_lane,
        to_arm=target.index,
        to_lane=to_lane,
        turn=turn,
        signal_id=signal_id,
        path_m=path,
        lane_id=None if abnormal else movement_id,
        abnormal=abnormal,
    )


def _u_turn_path(
    arm: Arm,
    start: NDArray[np.float64],
    end: NDArray[np.float64],
    radius_m: float,
    depth_m: float = 0.0,
) -> NDArray[np.float64]:
    """Into the junction (`depth_m` further than the shortest entry), swing right if the lanes
    are too close for the radius, loop back left on `radius_m` (at least half the lanes'
    distance), and drive out straight."""
    lateral_start = float(start @ arm.n)
    lateral_end = float(end @ arm.n)
    radius = max(radius_m, 0.5 * (lateral_start - lateral_end))
    loop_start_lateral = lateral_end + 2 * radius
    shift = loop_start_lateral - lateral_start
    entry_length = 4.0 + 1.4 * shift + depth_m
    loop_along = arm.stop_m - entry_length
    entry = cubic_bezier(
        start,
        arm.point(arm.stop_m - 0.5 * entry_length, lateral_start),
        arm.point(loop_along + 0.5 * entry_length, loop_start_lateral),
        arm.point(loop_along, loop_start_lateral),
        40,
    )
    centre_lateral = lateral_end + radius
    angles = np.linspace(0.0, np.pi, 60)
    loop = np.stack(
        [
            arm.point(loop_along - radius * np.sin(a), centre_lateral + radius * np.cos(a))
            for a in angles
        ]
    )
    exit_straight = np.stack([loop[-1], end])
    return np.concatenate([entry, loop[1:], exit_straight[1:]])


# ---------------------------------------------------------------------------- the map


def _mark(pattern: MarkPattern, colour: MarkColour) -> LaneMark:
    return LaneMark(pattern, colour)


def _straight_lane(
    lane_id: str,
    start: NDArray[np.float64],
    end: NDArray[np.float64],
    heading_left: NDArray[np.float64],
    left_mark: LaneMark,
    right_mark: LaneMark,
    predecessors: tuple[str, ...],
    successors: tuple[str, ...],
    left_neighbor: str | None,
    right_neighbor: str | None,
) -> Lane:
    centre = resample_polyline(np.stack([start, end]), 10.0)
    half = 0.5 * LANE_WIDTH_M * heading_left
    return Lane(
        lane_id=lane_id,
        centerline_m=centre,
        left_boundary_m=centre + half,
        right_boundary_m=centre - half,
        left_mark=left_mark,
        right_mark=right_mark,
        predecessors=predecessors,
        successors=successors,
        left_neighbor=left_neighbor,
        right_neighbor=right_neighbor,
        speed_limit_mps=SPEED_LIMIT_MPS,
    )


def _connector_lane(movement: Movement) -> Lane:
    path = movement.path_m
    delta = np.gradient(path, axis=0)
    normal = np.stack([-delta[:, 1], delta[:, 0]], axis=-1)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    half = 0.5 * LANE_WIDTH_M
    none = LaneMark()
    assert movement.lane_id is not None
    return Lane(
        lane_id=movement.lane_id,
        centerline_m=path,
        left_boundary_m=path + half * normal,
        right_boundary_m=path - half * normal,
        left_mark=none,
        right_mark=none,
        turn_direction=movement.turn,
        is_intersection=True,
        predecessors=(movement.from_lane,),
        successors=(movement.to_lane,),
        signal_id=movement.signal_id,
        speed_limit_mps=SPEED_LIMIT_MPS,
    )


def _build_map(
    map_id: str,
    origin: GeoOrigin,
    arms: tuple[Arm, ...],
    axes: tuple[tuple[int, ...], ...],
    protected_left: tuple[bool, ...],
    movements: tuple[Movement, ...],
    road: shapely.Polygon,
    rng: np.random.Generator,
) -> IntersectionMap:
    mapped = [m for m in movements if m.lane_id is not None]
    lanes: list[Lane] = []
    white_dashed = _mark(MarkPattern.DASHED, MarkColour.WHITE)
    white_solid = _mark(MarkPattern.SOLID, MarkColour.WHITE)
    yellow_double = _mark(MarkPattern.DOUBLE_SOLID, MarkColour.YELLOW)
    for arm in arms:
        for lane in range(arm.lanes_in):
            lane_id = incoming_lane_id(arm.index, lane)
            lanes.append(
                _straight_lane(
                    lane_id,
                    arm.point(ARM_LENGTH_M, arm.incoming_offset(lane)),
                    arm.point(arm.stop_m, arm.incoming_offset(lane)),
                    -arm.n,
                    yellow_double if lane == 0 else white_dashed,
                    white_solid if lane == arm.lanes_in - 1 else white_dashed,
                    (),
                    tuple(m.lane_id for m in mapped if m.from_lane == lane_id and m.lane_id),
                    incoming_lane_id(arm.index, lane - 1) if lane > 0 else None,
                    incoming_lane_id(arm.index, lane + 1) if lane < arm.lanes_in - 1 else None,
                )
            )
        for lane in range(arm.lanes_out):
            lane_id = outgoing_lane_id(arm.index, lane)
            lanes.append(
                _straight_lane(
                    lane_id,
                    arm.point(arm.stop_m, arm.outgoing_offset(lane)),
                    arm.point(ARM_LENGTH_M, arm.outgoing_offset(lane)),
                    arm.n,
                    yellow_double if lane == 0 else white_dashed,
                    white_solid if lane == arm.lanes_out - 1 else white_dashed,
                    tuple(m.lane_id for m in mapped if m.to_lane == lane_id and m.lane_id),
                    (),
                    outgoing_lane_id(arm.index, lane - 1) if lane > 0 else None,
                    outgoing_lane_id(arm.index, lane + 1) if lane < arm.lanes_out - 1 else None,
                )
            )
    lanes.extend(_connector_lane(m) for m in mapped)

    crosswalks, stop_lines, heads = [], [], []
    for arm in arms:
        width_out, width_in = arm.lanes_out * LANE_WIDTH_M, arm.lanes_in * LANE_WIDTH_M
        near, far = arm.junction_edge_m, arm.junction_edge_m + CROSSWALK_WIDTH_M
        crosswalks.append(
            Crosswalk(
                f"cw_a{arm.index}",
                np.stack(
                    [
                        arm.point(near, -width_out),
                        arm.point(far, -width_out),
                        arm.point(far, width_in),
                        arm.point(near, width_in),
                    ]
                ),
                signal_id=pedestrian_signal_id(arm.index),
            )
        )
        stop_lines.append(
            StopLine(
                f"stop_a{arm.index}",
                np.stack([arm.point(arm.stop_m, 0.0), arm.point(arm.stop_m, width_in)]),
                tuple(incoming_lane_id(arm.index, k) for k in range(arm.lanes_in)),
            )
        )
        heads.extend(_signal_heads(arm, axes, protected_left, mapped))
    sidewalks = _sidewalks(road)
    buildings = _buildings(arms, road, sidewalks, rng)
    trees = _trees(arms, rng)
    return IntersectionMap(
        map_id=map_id,
        origin=origin,
        lanes=tuple(lanes),
        crosswalks=tuple(crosswalks),
        stop_lines=tuple(stop_lines),
        drivable_areas=(Area("road", _outline(road)),),
        sidewalks=tuple(
            Area(f"sidewalk_{k}", poly, KERB_HEIGHT_M) for k, poly in enumerate(sidewalks)
        ),
        buildings=tuple(buildings),
        trees=tuple(trees),
        signal_heads=tuple(heads),
        metadata={
            "generator": "synthetic",
            "arms": [
                {
                    "angle_deg": float(np.rad2deg(a.angle_rad)),
                    "lanes_in": a.lanes_in,
                    "lanes_out": a.lanes_out,
                }
                for a in arms
            ],
            "protected_left_axes": [list(axes[k]) for k, p in enumerate(protected_left) if p],
        },
    )


def _road_polygon(arms: tuple[Arm, ...], movements: tuple[Movement, ...]) -> shapely.Polygon:
    """The carriageway: every arm, the junction's core between them, and the swept path of the
    design vehicle on every movement with its clearance (the corners' kerb lines)."""
    pieces = []
    for arm in arms:
        pieces.append(
            shapely.Polygon(
                [
                    arm.point(0.0, -arm.lanes_out * LANE_WIDTH_M),
                    arm.point(ARM_LENGTH_M, -arm.lanes_out * LANE_WIDTH_M),
                    arm.point(ARM_LENGTH_M, arm.lanes_in * LANE_WIDTH_M),
                    arm.point(0.0, arm.lanes_in * LANE_WIDTH_M),
                ]
            )
        )
    core = shapely.MultiPoint(
        [
            tuple(arm.point(arm.junction_edge_m, side * LANE_WIDTH_M * k))
            for arm in arms
            for side, k in ((-1, arm.lanes_out), (1, arm.lanes_in))
        ]
    ).convex_hull
    swept = [
        shapely.union_all(shapely.polygons(swept_boxes(m.path_m, DESIGN_VEHICLE_M))).buffer(
            TURN_KERB_CLEARANCE_M, quad_segs=4
        )
        for m in movements
    ]
    road = shapely.union_all([*pieces, core, *swept])
    return shapely.Polygon(road.exterior)


def _outline(polygon: shapely.Polygon) -> NDArray[np.float64]:
    simplified = polygon.simplify(0.01)
    return np.asarray(simplified.exterior.coords)[:-1, :2]


def _sidewalks(road: shapely.Polygon) -> list[NDArray[np.float64]]:
    reach = shapely.Point(0, 0).buffer(ARM_LENGTH_M - 0.5, quad_segs=32)
    ring = road.buffer(SIDEWALK_WIDTH_M, join_style="mitre").difference(road).intersection(reach)
    parts = list(getattr(ring, "geoms", [ring]))
    outlines = [_outline(p) for p in parts if isinstance(p, shapely.Polygon) and p.area > 1.0]
    return sorted(
        outlines, key=lambda o: (round(float(o[:, 0].mean()), 3), round(float(o[:, 1].mean()), 3))
    )


def _buildings(
    arms: tuple[Arm, ...],
    road: shapely.Polygon,
    sidewalks: list[NDArray[np.float64]],
    rng: np.random.Generator,
) -> list[Building]:
    keep_out = road.buffer(SIDEWALK_WIDTH_M + 2.0)
    placed: list[shapely.Polygon] = []
    buildings = []
    for arm in arms:
        for side, half_width in (
            (1, arm.lanes_in * LANE_WIDTH_M),
            (-1, arm.lanes_out * LANE_WIDTH_M),
        ):
            along = arm.junction_edge_m + 8.0
            while along < ARM_LENGTH_M - 20.0:
                frontage, depth = rng.uniform(12, 30), rng.uniform(10, 22)
                setback = half_width + SIDEWALK_WIDTH_M + rng.uniform(2.5, 6.0)
                corners = [
                    (along, setback),
                    (along + frontage, setback),
                    (along + frontage, setback + depth),
                    (along, setback + depth),
                ]
                footprint = shapely.Polygon([arm.point(a, side * lat) for a, lat in corners])
                if not footprint.intersects(keep_out) and not any(
                    footprint.intersects(p) for p in placed
                ):
                    placed.append(footprint)
                    buildings.append(
                        Building(
                            f"bld_{len(buildings):03d}",
                            np.asarray(footprint.exterior.coords)[:-1],
                            float(
                                rng.choice(
                                    [6.0, 9.0, 15.0, 24.0, 45.0], p=[0.25, 0.3, 0.2, 0.15, 0.1]
                                )
                            ),
                            generated=True,
                        )
                    )
                along += frontage + rng.uniform(3, 12)
    return buildings


def _trees(arms: tuple[Arm, ...], rng: np.random.Generator) -> list[Tree]:
    trees = []
    for arm in arms:
        for side, half_width in (
            (1, arm.lanes_in * LANE_WIDTH_M),
            (-1, arm.lanes_out * LANE_WIDTH_M),
        ):
            lateral = side * (half_width + SIDEWALK_WIDTH_M - 0.9)
            for along in np.arange(
                arm.junction_edge_m + 12.0, ARM_LENGTH_M - 5.0, rng.uniform(9, 14)
            ):
                trees.append(
                    Tree(
                        f"tree_{len(trees):03d}",
                        arm.point(float(along), lateral),
                        float(rng.uniform(5, 10)),
                        float(rng.uniform(1.5, 3.0)),
                    )
                )
    return trees


def _signal_heads(
    arm: Arm,
    axes: tuple[tuple[int, ...], ...],
    protected_left: tuple[bool, ...],
    mapped: list[Movement],
) -> list[SignalHead]:
    """Vehicle heads on a mast over the far side of the junction, facing the arm's traffic,
    and a pedestrian head at each end of the arm's crosswalk."""
    axis = next(k for k, group in enumerate(axes) if arm.index in group)
    signals = [through_signal_id(arm.index)]
    if protected_left[axis]:
        signals.insert(0, left_signal_id(arm.index))
    heads = []
    for k, signal_id in enumerate(signals):
        lane_ids = tuple(m.lane_id for m in mapped if m.signal_id == signal_id and m.lane_id)
        heads.append(
            SignalHead(
                f"head_a{arm.index}_{k}",
                signal_id,
                np.append(arm.point(-arm.junction_edge_m, (k + 0.5) * LANE_WIDTH_M), 5.5),
                arm.angle_rad,
                SignalKind.VEHICLE,
                lane_ids,
            )
        )
    middle = arm.junction_edge_m + 0.5 * CROSSWALK_WIDTH_M
    setback = PEDESTRIAN_SIGNAL_SETBACK_M
    for end, lateral in enumerate(
        (-(arm.lanes_out * LANE_WIDTH_M + setback), arm.lanes_in * LANE_WIDTH_M + setback)
    ):
        facing = arm.angle_rad + (np.pi / 2 if end == 0 else -np.pi / 2)
        heads.append(
            SignalHead(
                f"head_a{arm.index}_ped{end}",
                pedestrian_signal_id(arm.index),
                np.append(arm.point(middle, lateral), 2.5),
                float(wrap_angle(facing)),
                SignalKind.PEDESTRIAN,
            )
        )
    return heads
