"""The HD map of one intersection: lanes, crosswalks, stop lines, kerbside areas and signals.

Coordinates are metres in the intersection's local ENU frame, whose WGS84 origin is `origin`.
Polylines are `(N, 3)` (x, y, z); polygons are `(N, 2)` outlines without a repeated end point.
Construction validates ids, shapes and every cross-reference, raising `MapFormatError`.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np
import shapely
from numpy.typing import NDArray

from drivee2e_data.arrays import ArrayValueEq, frozen_array
from drivee2e_data.errors import MapFormatError


class MarkPattern(enum.Enum):
    NONE = "none"
    SOLID = "solid"
    DASHED = "dashed"
    DOUBLE_SOLID = "double_solid"
    SOLID_DASHED = "solid_dashed"  # solid on the left of travel, dashed on the right
    DASHED_SOLID = "dashed_solid"
    DOUBLE_DASHED = "double_dashed"


class MarkColour(enum.Enum):
    NONE = "none"
    WHITE = "white"
    YELLOW = "yellow"
    BLUE = "blue"


@dataclass(frozen=True)
class LaneMark:
    """The painted line along one lane boundary."""

    pattern: MarkPattern = MarkPattern.NONE
    colour: MarkColour = MarkColour.NONE

    def to_text(self) -> str:
        return f"{self.pattern.value}:{self.colour.value}"

    @classmethod
    def from_text(cls, text: str) -> LaneMark:
        pattern, _, colour = text.partition(":")
        return cls(MarkPattern(pattern), MarkColour(colour or "none"))


class TurnDirection(enum.Enum):
    NONE = "none"  # a lane outside the junction
    STRAIGHT = "straight"
    LEFT = "left"
    RIGHT = "right"
    U_TURN = "u_turn"


class LaneType(enum.Enum):
    VEHICLE = "vehicle"
    BIKE = "bike"
    BUS = "bus"


class SignalKind(enum.Enum):
    VEHICLE = "vehicle"
    PEDESTRIAN = "pedestrian"


@dataclass(frozen=True)
class GeoOrigin:
    """WGS84 position of the local frame's origin."""

    latitude_deg: float
    longitude_deg: float
    altitude_m: float = 0.0

    def __post_init__(self) -> None:
        if not (-90.0 <= self.latitude_deg <= 90.0 and -180.0 <= self.longitude_deg <= 180.0):
            raise MapFormatError(
                f"origin: ({self.latitude_deg}, {self.longitude_deg}) is not a WGS84 latitude/longitude"
            )


def line_heading_at(
    line: shapely.LineString, point: shapely.Point, half_window_m: float = 0.5
) -> float:
    """Heading (rad) of `line` at the point nearest `point`, over +-`half_window_m`."""
    s = line.project(point)
    a = line.interpolate(max(s - half_window_m, 0.0))
    b = line.interpolate(min(s + half_window_m, line.length))
    return float(np.arctan2(b.y - a.y, b.x - a.x))


def _polyline(where: str, values: object, min_points: int = 2) -> NDArray[np.float64]:
    array = frozen_array(values, np.float64)
    if array.ndim != 2 or array.shape[1] not in (2, 3):
        raise MapFormatError(
            f"{where}: expected an (N, 2) or (N, 3) array, got shape {array.shape}"
        )
    if array.shape[1] == 2:
        array = frozen_array(np.column_stack([array, np.zeros(len(array))]), np.float64)
    if len(array) < min_points:
        raise MapFormatError(f"{where}: expected at least {min_points} points, got {len(array)}")
    bad = np.flatnonzero(~np.isfinite(array).all(axis=1))
    if bad.size:
        raise MapFormatError(f"{where}: point {bad[0]} is not finite: {array[bad[0]].tolist()}")
    return array


def _polygon(where: str, values: object) -> NDArray[np.float64]:
    array = frozen_array(values, np.float64)
    if array.ndim != 2 or array.shape[1] != 2 or len(array) < 3:
        raise MapFormatError(f"{where}: expected an (N>=3, 2) outline, got shape {array.shape}")
    bad = np.flatnonzero(~np.isfinite(array).all(axis=1))
    if bad.size:
        raise MapFormatError(f"{where}: vertex {bad[0]} is not finite: {array[bad[0]].tolist()}")
    return array


@dataclass(frozen=True, eq=False)
class Lane(ArrayValueEq):
    """One lane: centreline and boundaries `(N, 3)` in travel order, topology, controlling signal."""

    lane_id: str
    centerline_m: NDArray[np.float64]
    left_boundary_m: NDArray[np.float64]
    right_boundary_m: NDArray[np.float64]
    left_mark: LaneMark = LaneMark()
    right_mark: LaneMark = LaneMark()
    lane_type: LaneType = LaneType.VEHICLE
    turn_direction: TurnDirection = TurnDirection.NONE
    is_intersection: bool = False
    predecessors: tuple[str, ...] = ()
    successors: tuple[str, ...] = ()
    left_neighbor: str | None = None
    right_neighbor: str | None = None
    signal_id: str | None = None
    speed_limit_mps: float | None = None

    def __post_init__(self) -> None:
        where = f"lane {self.lane_id!r}"
        for name in ("centerline_m", "left_boundary_m", "right_boundary_m"):
            object.__setattr__(self, name, _polyline(f"{where}.{name}", getattr(self, name)))
        object.__setattr__(self, "predecessors", tuple(self.predecessors))
        object.__setattr__(self, "successors", tuple(self.successors))

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(np.diff(self.centerline_m[:, :2], axis=0), axis=1).sum())

    def heading_at(self, x_m: float, y_m: float, half_window_m: float = 0.5) -> float:
        """Heading (rad) of the centre line at the point nearest (x, y), over +-`half_window_m`."""
        line = shapely.LineString(self.centerline_m[:, :2])
        return line_heading_at(line, shapely.Point(x_m, y_m), half_window_m)

    def polygon(self) -> shapely.Polygon:
        """The lane's surface as a polygon (left boundary forward, right boundary back)."""
        ring = np.concatenate([self.left_boundary_m[:, :2], self.right_boundary_m[::-1, :2]])
        return shapely.make_valid(shapely.Polygon(ring))


@dataclass(frozen=True, eq=False)
class Crosswalk(ArrayValueEq):
    crosswalk_id: str
    polygon_m: NDArray[np.float64]
    signal_id: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "polygon_m", _polygon(f"crosswalk {self.crosswalk_id!r}", self.polygon_m)
        )


@dataclass(frozen=True, eq=False)
class StopLine(ArrayValueEq):
    """A stop line `(N, 3)` across the lanes in `lane_ids`; `derived` when placed by an importer."""

    stop_line_id: str
    line_m: NDArray[np.float64]
    lane_ids: tuple[str, ...] = ()
    derived: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "line_m", _polyline(f"stop line {self.stop_line_id!r}", self.line_m)
        )
        object.__setattr__(self, "lane_ids", tuple(self.lane_ids))


@dataclass(frozen=True, eq=False)
class Area(ArrayValueEq):
    """A flat area given by its outline: drivable surface or sidewalk (`kerb_height_m` above road)."""

    area_id: str
    polygon_m: NDArray[np.float64]
    kerb_height_m: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "polygon_m", _polygon(f"area {self.area_id!r}", self.polygon_m))


@dataclass(frozen=True, eq=False)
class Kerb(ArrayValueEq):
    """A kerb line `(N, 3)` between road and a raised area, `height_m` above the road."""

    kerb_id: str
    line_m: NDArray[np.float64]
    height_m: float = 0.15

    def __post_init__(self) -> None:
        object.__setattr__(self, "line_m", _polyline(f"kerb {self.kerb_id!r}", self.line_m))


@dataclass(frozen=True, eq=False)
class Building(ArrayValueEq):
    """A building footprint `(N, 2)` extruded to `height_m`; `generated` when not from the source."""

    building_id: str
    footprint_m: NDArray[np.float64]
    height_m: float
    generated: bool = False

    def __post_init__(self) -> None:
        where = f"building {self.building_id!r}"
        object.__setattr__(self, "footprint_m", _polygon(where, self.footprint_m))
        if not (np.isfinite(self.height_m) and self.height_m > 0):
            raise MapFormatError(f"{where}.height_m: expected > 0, got {self.height_m}")


@dataclass(frozen=True, eq=False)
class Tree(ArrayValueEq):
    tree_id: str
    position_m: NDArray[np.float64]
    height_m: float
    crown_radius_m: float

    def __post_init__(self) -> None:
        position = frozen_array(self.position_m, np.float64)
        if position.shape != (2,) or not np.isfinite(position).all():
            raise MapFormatError(f"tree {self.tree_id!r}.position_m: expected 2 finite values")
        object.__setattr__(self, "position_m", position)


@dataclass(frozen=True, eq=False)
class SignalHead(ArrayValueEq):
    """A physical signal head showing the state of `signal_id`, facing `facing_yaw_rad`."""

    head_id: str
    signal_id: str
    position_m: NDArray[np.float64]
    facing_yaw_rad: float
    kind: SignalKind = SignalKind.VEHICLE
    controlled_lane_ids: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        position = frozen_array(self.position_m, np.float64)
        if position.shape != (3,) or not np.isfinite(position).all():
            raise MapFormatError(
                f"signal head {self.head_id!r}.position_m: expected 3 finite values"
            )
        object.__setattr__(self, "position_m", position)
        object.__setattr__(self, "controlled_lane_ids", tuple(self.controlled_lane_ids))


@dataclass(frozen=True, eq=False)
class StaticObstacle(ArrayValueEq):
    """A fixed object that is not an agent (bollard, cone, sign): a box on the ground."""

    obstacle_id: str
    kind: str
    position_m: NDArray[np.float64]
    yaw_rad: float
    size_m: NDArray[np.float64]  # (length, width, height)

    def __post_init__(self) -> None:
        for name, shape in (("position_m", (3,)), ("size_m", (3,))):
            values = frozen_array(getattr(self, name), np.float64)
            if values.shape != shape or not np.isfinite(values).all():
                raise MapFormatError(
                    f"obstacle {self.obstacle_id!r}.{name}: expected 3 finite values"
                )
            object.__setattr__(self, name, values)


@dataclass(frozen=True, eq=False)
class IntersectionMap(ArrayValueEq):
    """Everything static about one intersection, validated on construction."""

    map_id: str
    origin: GeoOrigin
    lanes: tuple[Lane, ...]
    crosswalks: tuple[Crosswalk, ...] = ()
    stop_lines: tuple[StopLine, ...] = ()
    drivable_areas: tuple[Area, ...] = ()
    sidewalks: tuple[Area, ...] = ()
    kerbs: tuple[Kerb, ...] = ()
    buildings: tuple[Building, ...] = ()
    trees: tuple[Tree, ...] = ()
    signal_heads: tuple[SignalHead, ...] = ()
    static_obstacles: tuple[StaticObstacle, ...] = ()
    metadata: Mapping[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.map_id, str) or not self.map_id or "/" in self.map_id:
            raise MapFormatError(f"map_id: expected a plain non-empty name, got {self.map_id!r}")
        for name in (
            "lanes",
            "crosswalks",
            "stop_lines",
            "drivable_areas",
            "sidewalks",
            "kerbs",
            "buildings",
            "trees",
            "signal_heads",
            "static_obstacles",
        ):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        _unique("lane", (lane.lane_id for lane in self.lanes))
        _unique("crosswalk", (c.crosswalk_id for c in self.crosswalks))
        _unique("stop line", (s.stop_line_id for s in self.stop_lines))
        _unique("area", (a.area_id for a in (*self.drivable_areas, *self.sidewalks)))
        _unique("kerb", (k.kerb_id for k in self.kerbs))
        _unique("building", (b.building_id for b in self.buildings))
        _unique("tree", (t.tree_id for t in self.trees))
        _unique("signal head", (h.head_id for h in self.signal_heads))
        _unique("static obstacle", (o.obstacle_id for o in self.static_obstacles))
        self._check_references()

    def _check_references(self) -> None:
        lane_ids = {lane.lane_id for lane in self.lanes}
        signal_ids = {head.signal_id for head in self.signal_heads}

        def need_lane(where: str, lane_id: str | None) -> None:
            if lane_id is not None and lane_id not in lane_ids:
                raise MapFormatError(f"{where} references lane {lane_id!r}, which the map lacks")

        for lane in self.lanes:
            where = f"lane {lane.lane_id!r}"
            for other in lane.predecessors:
                need_lane(f"{where}.predecessors", other)
            for other in lane.successors:
                need_lane(f"{where}.successors", other)
            need_lane(f"{where}.left_neighbor", lane.left_neighbor)
            need_lane(f"{where}.right_neighbor", lane.right_neighbor)
            if lane.signal_id is not None and lane.signal_id not in signal_ids:
                raise MapFormatError(
                    f"{where}.signal_id references signal {lane.signal_id!r}, which no head shows"
                )
        for stop_line in self.stop_lines:
            for lane_id in stop_line.lane_ids:
                need_lane(f"stop line {stop_line.stop_line_id!r}.lane_ids", lane_id)
        for head in self.signal_heads:
            for lane_id in head.controlled_lane_ids:
                need_lane(f"signal head {head.head_id!r}.controlled_lane_ids", lane_id)

    def lane(self, lane_id: str) -> Lane:
        for lane in self.lanes:
            if lane.lane_id == lane_id:
                return lane
        raise KeyError(f"map {self.map_id!r} has no lane {lane_id!r}")

    @property
    def signal_ids(self) -> list[str]:
        """Distinct signal ids shown by the map's heads, in first-seen order."""
        return list(dict.fromkeys(head.signal_id for head in self.signal_heads))

    def drivable_union(self) -> shapely.Geometry:
        """Union of the drivable areas (or of the lane polygons when the map has none)."""
        if self.drivable_areas:
            return shapely.union_all([shapely.Polygon(a.polygon_m) for a in self.drivable_areas])
        return shapely.union_all([lane.polygon() for lane in self.lanes])


def _unique(kind: str, ids: Iterable[str]) -> None:
    seen: set[str] = set()
    for index, item in enumerate(ids):
        if not isinstance(item, str) or not item:
            raise MapFormatError(f"{kind} at index {index}: id must be a non-empty string")
        if item in seen:
            raise MapFormatError(f"{kind} id {item!r} at index {index} is not unique")
        seen.add(item)
