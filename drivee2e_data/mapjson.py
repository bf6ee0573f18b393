"""JSON form of `IntersectionMap`: plain lists and strings, lossless for float64 coordinates."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from drivee2e_data.errors import MapFormatError
from drivee2e_data.hdmap import (
    Area,
    Building,
    Crosswalk,
    GeoOrigin,
    IntersectionMap,
    Kerb,
    Lane,
    LaneMark,
    LaneType,
    SignalHead,
    SignalKind,
    StaticObstacle,
    StopLine,
    Tree,
    TurnDirection,
)


def map_to_dict(intersection_map: IntersectionMap) -> dict[str, Any]:
    """A JSON-ready dict of the map; `map_from_dict` inverts it exactly."""
    m = intersection_map
    return {
        "map_id": m.map_id,
        "origin": {
            "latitude_deg": m.origin.latitude_deg,
            "longitude_deg": m.origin.longitude_deg,
            "altitude_m": m.origin.altitude_m,
        },
        "lanes": [
            {
                "id": lane.lane_id,
                "centerline_m": lane.centerline_m.tolist(),
                "left_boundary_m": lane.left_boundary_m.tolist(),
                "right_boundary_m": lane.right_boundary_m.tolist(),
                "left_mark": lane.left_mark.to_text(),
                "right_mark": lane.right_mark.to_text(),
                "lane_type": lane.lane_type.value,
                "turn_direction": lane.turn_direction.value,
                "is_intersection": lane.is_intersection,
                "predecessors": list(lane.predecessors),
                "successors": list(lane.successors),
                "left_neighbor": lane.left_neighbor,
                "right_neighbor": lane.right_neighbor,
                "signal_id": lane.signal_id,
                "speed_limit_mps": lane.speed_limit_mps,
            }
            for lane in m.lanes
        ],
        "crosswalks": [
            {"id": c.crosswalk_id, "polygon_m": c.polygon_m.tolist(), "signal_id": c.signal_id}
            for c in m.crosswalks
        ],
        "stop_lines": [
            {
                "id": s.stop_line_id,
                "line_m": s.line_m.tolist(),
                "lane_ids": list(s.lane_ids),
                "derived": s.derived,
            }
            for s in m.stop_lines
        ],
        "drivable_areas": [_area(a) for a in m.drivable_areas],
        "sidewalks": [_area(a) for a in m.sidewalks],
        "kerbs": [
            {"id": k.kerb_id, "line_m": k.line_m.tolist(), "height_m": k.height_m} for k in m.kerbs
        ],
        "buildings": [
            {
                "id": b.building_id,
                "footprint_m": b.footprint_m.tolist(),
                "height_m": b.height_m,
                "generated": b.generated,
            }
            for b in m.buildings
        ],
        "trees": [
            {
                "id": t.tree_id,
                "position_m": t.position_m.tolist(),
                "height_m": t.height_m,
                "crown_radius_m": t.crown_radius_m,
            }
            for t in m.trees
        ],
        "signal_heads": [
            {
                "id": h.head_id,
                "signal_id": h.signal_id,
                "position_m": h.position_m.tolist(),
                "facing_yaw_rad": h.facing_yaw_rad,
                "kind": h.kind.value,
                "controlled_lane_ids": list(h.controlled_lane_ids),
            }
            for h in m.signal_heads
        ],
        "static_obstacles": [
            {
                "id": o.obstacle_id,
                "kind": o.kind,
                "position_m": o.position_m.tolist(),
                "yaw_rad": o.yaw_rad,
                "size_m": o.size_m.tolist(),
            }
            for o in m.static_obstacles
        ],
        "metadata": dict(m.metadata),
    }


def _area(area: Area) -> dict[str, Any]:
    return {
        "id": area.area_id,
        "polygon_m": area.polygon_m.tolist(),
        "kerb_height_m": area.kerb_height_m,
    }


class _Reader:
    """Reads keys of one JSON object and names `where` and the key in every error."""

    def __init__(self, document: Any, where: str) -> None:
        if not isinstance(document, dict):
            raise MapFormatError(f"{where}: expected an object, got {type(document).__name__}")
        self.document, self.where = document, where

    def get(self, key: str, parse: Callable[[Any], Any] = lambda v: v, default: Any = ...) -> Any:
        if key not in self.document:
            if default is ...:
                raise MapFormatError(f"{self.where}: key {key!r} is missing")
            return default
        value = self.document[key]
        try:
            return parse(value)
        except MapFormatError as error:
            raise MapFormatError(f"{self.where}.{key}: {error}") from None
        except (ValueError, TypeError, KeyError) as error:
            raise MapFormatError(f"{self.where}.{key}: {value!r} is not valid ({error})") from None

    def items(self, key: str) -> list[_Reader]:
        values = self.get(key, default=[])
        if not isinstance(values, list):
            raise MapFormatError(f"{self.where}.{key}: expected a list")
        return [_Reader(v, f"{self.where}.{key}[{i}]") for i, v in enumerate(values)]


def _array(value: Any) -> np.ndarray:
    return np.asarray(value, dtype=np.float64)


def _optional_str(value: Any) -> str | None:
    return None if value is None else str(value)


def map_from_dict(document: dict[str, Any], where: str = "map") -> IntersectionMap:
    """Build and validate an `IntersectionMap` from `map_to_dict` output; errors name `where`."""
    root = _Reader(document, where)
    origin = root.get("origin", lambda o: GeoOrigin(**o))
    try:
        return IntersectionMap(
            map_id=root.get("map_id", str),
            origin=origin,
            lanes=tuple(
                Lane(
                    lane_id=r.get("id", str),
                    centerline_m=r.get("centerline_m", _array),
                    left_boundary_m=r.get("left_boundary_m", _array),
                    right_boundary_m=r.get("right_boundary_m", _array),
                    left_mark=r.get("left_mark", LaneMark.from_text, LaneMark()),
                    right_mark=r.get("right_mark", LaneMark.from_text, LaneMark()),
                    lane_type=r.get("lane_type", LaneType, LaneType.VEHICLE),
                    turn_direction=r.get("turn_direction", TurnDirection, TurnDirection.NONE),
                    is_intersection=r.get("is_intersection", bool, False),
                    predecessors=tuple(r.get("predecessors", list, [])),
                    successors=tuple(r.get("successors", list, [])),
                    left_neighbor=r.get("left_neighbor", _optional_str, None),
                    right_neighbor=r.get("right_neighbor", _optional_str, None),
                    signal_id=r.get("signal_id", _optional_str, None),
                    speed_limit_mps=r.get("speed_limit_mps", default=None),
                )
                for r in root.items("lanes")
            ),
            crosswalks=tuple(
                Crosswalk(
                    r.get("id", str),
                    r.get("polygon_m", _array),
                    r.get("signal_id", _optional_str, None),
                )
                for r in root.items("crosswalks")
            ),
            stop_lines=tuple(
                StopLine(
                    r.get("id", str),
                    r.get("line_m", _array),
                    tuple(r.get("lane_ids", list, [])),
                    r.get("derived", bool, False),
                )
                for r in root.items("stop_lines")
            ),
            drivable_areas=tuple(_area_from(r) for r in root.items("drivable_areas")),
            sidewalks=tuple(_area_from(r) for r in root.items("sidewalks")),
            kerbs=tuple(
                Kerb(r.get("id", str), r.get("line_m", _array), r.get("height_m", float, 0.15))
                for r in root.items("kerbs")
            ),
            buildings=tuple(
                Building(
                    r.get("id", str),
                    r.get("footprint_m", _array),
                    r.get("height_m", float),
                    r.get("generated", bool, False),
                )
                for r in root.items("buildings")
            ),
            trees=tuple(
                Tree(
                    r.get("id", str),
                    r.get("position_m", _array),
                    r.get("height_m", float),
                    r.get("crown_radius_m", float),
                )
                for r in root.items("trees")
            ),
            signal_heads=tuple(
                SignalHead(
                    head_id=r.get("id", str),
                    signal_id=r.get("signal_id", str),
                    position_m=r.get("position_m", _array),
                    facing_yaw_rad=r.get("facing_yaw_rad", float),
                    kind=r.get("kind", SignalKind, SignalKind.VEHICLE),
                    controlled_lane_ids=tuple(r.get("controlled_lane_ids", list, [])),
                )
                for r in root.items("signal_heads")
            ),
            static_obstacles=tuple(
                StaticObstacle(
                    r.get("id", str),
                    r.get("kind", str),
                    r.get("position_m", _array),
                    r.get("yaw_rad", float),
                    r.get("size_m", _array),
                )
                for r in root.items("static_obstacles")
            ),
            metadata=root.get("metadata", dict, {}),
        )
    except MapFormatError as error:
        if str(error).startswith(where):
            raise
        raise MapFormatError(f"{where}: {error}") from None


def _area_from(reader: _Reader) -> Area:
    return Area(
        reader.get("id", str),
        reader.get("polygon_m", _array),
        reader.get("kerb_height_m", float, 0.0),
    )
