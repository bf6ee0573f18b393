"""Lanelet2 maps (OSM XML), as used by the Lanelet2 examples, SinD and INTERACTION.

Parsed from the XML directly rather than through the `lanelet2` package: the maps of SinD mark
crosswalks with plain `zebra`/`zebra_marking` ways that are not Lanelet2 primitives, and only
nodes, ways, lanelet relations and regulatory elements are needed. Coordinates project from
lat/lon with the UTM zone of the origin, minus the origin's own projection (the Lanelet2
`UtmProjector` convention; SinD and INTERACTION use the origin (0, 0)).
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import shapely
from numpy.typing import NDArray

from drivee2e_data.errors import MapFormatError
from drivee2e_data.geometry import centerline_between
from drivee2e_data.hdmap import (
    Area,
    Crosswalk,
    GeoOrigin,
    IntersectionMap,
    Kerb,
    Lane,
    LaneMark,
    LaneType,
    MarkColour,
    MarkPattern,
    SignalHead,
    StopLine,
)
from drivee2e_data.sources.common import (
    ImportReport,
    link_lanes_by_geometry,
    utm_transformer,
    utm_zone_of,
)

ROAD_SUBTYPES = {None, "road", "highway", "main_road", "bus_lane", "bicycle_lane", "play_street"}
PATTERNS = {
    "solid": MarkPattern.SOLID,
    "dashed": MarkPattern.DASHED,
    "solid_solid": MarkPattern.DOUBLE_SOLID,
    "dashed_solid": MarkPattern.DASHED_SOLID,
    "solid_dashed": MarkPattern.SOLID_DASHED,
}
STOP_LINE_REACH_M = 3.0  # a lane ending this close to a stop line is the stop line's lane


@dataclass(frozen=True)
class OsmData:
    nodes: dict[str, NDArray[np.float64]]  # id -> (x, y, z) in the local frame
    ways: dict[str, tuple[list[str], dict[str, str]]]
    relations: dict[
        str, tuple[list[tuple[str, str, str]], dict[str, str]]
    ]  # members (type, ref, role)
    origin: GeoOrigin
    cropped_ways: int = 0  # ways dropped because a crop removed some of their nodes


def read_osm(path: Path, origin: tuple[float, float] | None = None) -> OsmData:
    """Nodes projected to the local frame, ways and relations; `origin` (lat, lon) defaults to
    the mean of the nodes."""
    path = Path(path)
    if not path.is_file():
        raise MapFormatError(f"{path}: file is missing")
    try:
        root = ElementTree.parse(path).getroot()
    except ElementTree.ParseError as error:
        raise MapFormatError(f"{path}: not valid OSM XML ({error})") from None
    raw = {}
    for node in root.iter("node"):
        try:
            tags = {t.get("k"): t.get("v") for t in node.findall("tag")}
            raw[node.get("id")] = (
                float(node.get("lat")),
                float(node.get("lon")),
                float(tags.get("ele", 0.0)),
            )
        except (TypeError, ValueError):
            raise MapFormatError(f"{path}: node {node.get('id')!r} has no valid lat/lon") from None
    if not raw:
        raise MapFormatError(f"{path}: no nodes")
    values = np.array(list(raw.values()))
    if origin is None:
        origin = (float(values[:, 0].mean()), float(values[:, 1].mean()))
    zone = utm_zone_of(origin[1])
    forward = utm_transformer(zone, northern=origin[0] >= 0)
    origin_e, origin_n = forward.transform(origin[1], origin[0])
    east, north = forward.transform(values[:, 1], values[:, 0])
    local = np.stack([np.asarray(east) - origin_e, np.asarray(north) - origin_n, values[:, 2]], -1)
    nodes = {node_id: local[k] for k, node_id in enumerate(raw)}
    ways, cropped = {}, 0
    for way in root.iter("way"):
        refs = [nd.get("ref") for nd in way.findall("nd")]
        if any(ref not in nodes for ref in refs):  # cut by a map crop: dropped, counted
            cropped += 1
            continue
        ways[way.get("id")] = (refs, {t.get("k"): t.get("v") for t in way.findall("tag")})
    relations = {}
    for relation in root.iter("relation"):
        members = [(m.get("type"), m.get("ref"), m.get("role")) for m in relation.findall("member")]
        relations[relation.get("id")] = (
            members,
            {t.get("k"): t.get("v") for t in relation.findall("tag")},
        )
    return OsmData(nodes, ways, relations, GeoOrigin(origin[0], origin[1]), cropped)


def _line(osm: OsmData, way_id: str) -> NDArray[np.float64]:
    return np.array([osm.nodes[ref] for ref in osm.ways[way_id][0]])


def _mark(tags: dict[str, str]) -> LaneMark:
    if tags.get("type") not in ("line_thin", "line_thick"):
        return LaneMark()
    colour = MarkColour.YELLOW if tags.get("color") == "yellow" else MarkColour.WHITE
    return LaneMark(PATTERNS.get(tags.get("subtype", "solid"), MarkPattern.SOLID), colour)


def _bounds(osm: OsmData, path: Path, relation_id: str) -> tuple[NDArray, NDArray, str, str] | None:
    members, _ = osm.relations[relation_id]
    left = [ref for kind, ref, role in members if kind == "way" and role == "left"]
    right = [ref for kind, ref, role in members if kind == "way" and role == "right"]
    if not left or not right:
        return None
    if left[0] not in osm.ways or right[0] not in osm.ways:
        return None  # a bound lies outside the map crop
    left_line, right_line = _line(osm, left[0]), _line(osm, right[0])
    if np.linalg.norm(left_line[0] - right_line[0]) + np.linalg.norm(
        left_line[-1] - right_line[-1]
    ) > (
        np.linalg.norm(left_line[0] - right_line[-1])
        + np.linalg.norm(left_line[-1] - right_line[0])
    ):
        right_line = right_line[::-1]
    travel = left_line[-1, :2] - left_line[0, :2]
    side = left_line[len(left_line) // 2, :2] - right_line[len(right_line) // 2, :2]
    if travel[0] * side[1] - travel[1] * side[0] < 0:  # the left bound lies on the right
        left_line, right_line = left_line[::-1], right_line[::-1]
    return left_line, right_line, left[0], right[0]


def _zebra_crosswalks(osm: OsmData) -> list[Crosswalk]:
    """Crosswalks from pairs of zebra ways (SinD): ways with the same `direction` tag pair up,
    otherwise each pairs with its nearest unpaired neighbour."""
    zebras = [
        way_id
        for way_id, (_, tags) in osm.ways.items()
        if tags.get("type") in ("zebra", "zebra_marking")
    ]
    lines = {way_id: _line(osm, way_id)[:, :2] for way_id in zebras}
    middle = {way_id: line.mean(axis=0) for way_id, line in lines.items()}
    unpaired, crosswalks = sorted(zebras), []
    while len(unpaired) >= 2:
        first = unpaired.pop(0)
        direction = osm.ways[first][1].get("direction")
        pool = (
            [w for w in unpaired if osm.ways[w][1].get("direction") == direction]
            if direction
            else unpaired
        )
        if not pool:
            continue
        partner = min(pool, key=lambda w: np.linalg.norm(middle[w] - middle[first]))
        unpaired.remove(partner)
        a, b = lines[first], lines[partner]
        if np.linalg.norm(a[0] - b[0]) < np.linalg.norm(a[0] - b[-1]):
            b = b[::-1]
        polygon = shapely.Polygon(np.concatenate([a, b])).convex_hull
        if polygon.area > 1.0:
            crosswalks.append(Crosswalk(f"zebra_{first}", np.asarray(polygon.exterior.coords)[:-1]))
    return crosswalks


def read_map(
    path: Path,
    map_id: str,
    origin: tuple[float, float] | None = None,
    report: ImportReport | None = None,
) -> IntersectionMap:
    """A Lanelet2 OSM map as an `IntersectionMap` in its local projected frame. A map cropped to
    one site keeps ways and lanelets whose nodes or bounds lie outside it: those are dropped and
    counted in one warning on `report`."""
    path = Path(path)
    osm = read_osm(path, origin)
    cropped_lanelets = 0
    lanes, crosswalks, sidewalks = [], [], []
    light_of_lane: dict[str, str] = {}
    lights = {
        rid: (members, tags)
        for rid, (members, tags) in osm.relations.items()
        if tags.get("type") == "regulatory_element" and tags.get("subtype") == "traffic_light"
    }
    for relation_id, (members, tags) in osm.relations.items():
        if tags.get("type") != "lanelet":
            continue
        bound_refs = [ref for kind, ref, role in members if role in ("left", "right")]
        if any(ref not in osm.ways for ref in bound_refs):
            cropped_lanelets += 1
            continue
        bounds = _bounds(osm, path, relation_id)
        if bounds is None:
            continue
        left, right, left_way, right_way = bounds
        subtype = tags.get("subtype")
        outline = np.concatenate([left[:, :2], right[::-1, :2]])
        if subtype == "crosswalk":
            crosswalks.append(Crosswalk(f"crosswalk_{relation_id}", outline))
        elif subtype in ("walkway", "stairs"):
            sidewalks.append(Area(f"walkway_{relation_id}", outline))
        elif subtype in ROAD_SUBTYPES:
            lane_id = f"lanelet_{relation_id}"
            for kind, ref, role in members:
                if kind == "relation" and role == "regulatory_element" and ref in lights:
                    light_of_lane[lane_id] = f"light_{ref}"
            lanes.append(
                Lane(
                    lane_id=lane_id,
                    centerline_m=centerline_between(left, right),
                    left_boundary_m=left,
                    right_boundary_m=right,
                    left_mark=_mark(osm.ways[left_way][1]),
                    right_mark=_mark(osm.ways[right_way][1]),
                    lane_type=LaneType.BIKE if subtype == "bicycle_lane" else LaneType.VEHICLE,
                    signal_id=light_of_lane.get(lane_id),
                )
            )
    lanes = link_lanes_by_geometry(lanes)
    if (cropped_lanelets or osm.cropped_ways) and report is not None:
        report.warn(
            f"{path.name}: {cropped_lanelets} lanelets and {osm.cropped_ways} ways reach outside "
            "the map crop; dropped"
        )
    if not crosswalks:
        crosswalks = _zebra_crosswalks(osm)
    stop_lines = []
    for way_id, (_, tags) in osm.ways.items():
        if tags.get("type") != "stop_line":
            continue
        line = _line(osm, way_id)
        geometry = shapely.LineString(line[:, :2])
        near = tuple(
            lane.lane_id
            for lane in lanes
            if geometry.distance(shapely.Point(lane.centerline_m[-1, :2])) < STOP_LINE_REACH_M
        )
        stop_lines.append(StopLine(f"stop_{way_id}", line, near))
    heads = []
    for relation_id, (members, _) in lights.items():
        signal_id = f"light_{relation_id}"
        refers = [
            ref
            for kind, ref, role in members
            if kind == "way" and role == "refers" and ref in osm.ways
        ]
        controlled = tuple(
            lane_id for lane_id, light in light_of_lane.items() if light == signal_id
        )
        for index, ref in enumerate(refers or []):
            line = _line(osm, ref)
            height = float(osm.ways[ref][1].get("height", 0.0) or 0.0)
            position = np.append(line[:, :2].mean(axis=0), max(height, 5.0))
            facing = 0.0
            if controlled:
                lane = next(la for la in lanes if la.lane_id == controlled[0])
                back = lane.centerline_m[-2, :2] - lane.centerline_m[-1, :2]
                facing = float(np.arctan2(back[1], back[0]))
            heads.append(
                SignalHead(
                    f"head_{relation_id}_{index}",
                    signal_id,
                    position,
                    facing,
                    controlled_lane_ids=controlled,
                )
            )
    shown = {head.signal_id for head in heads}
    lanes = [lane if lane.signal_id in shown else replace(lane, signal_id=None) for lane in lanes]
    kerbs = tuple(
        Kerb(f"kerb_{way_id}", _line(osm, way_id), 0.15 if tags.get("subtype") != "high" else 0.25)
        for way_id, (refs, tags) in osm.ways.items()
        if tags.get("type") == "curbstone" and len(refs) >= 2
    )
    road = shapely.union_all([lane.polygon() for lane in lanes]) if lanes else shapely.Polygon()
    parts = [
        p for p in getattr(road, "geoms", [road]) if isinstance(p, shapely.Polygon) and p.area > 1.0
    ]
    areas = tuple(
        Area(f"road_{k}", np.asarray(p.exterior.coords)[:-1, :2]) for k, p in enumerate(parts)
    )
    return IntersectionMap(
        map_id=map_id,
        origin=osm.origin,
        lanes=tuple(lanes),
        crosswalks=tuple(crosswalks),
        stop_lines=tuple(stop_lines),
        drivable_areas=areas,
        sidewalks=tuple(sidewalks),
        kerbs=kerbs,
        signal_heads=tuple(heads),
        metadata={
            "source": "lanelet2",
            "file": path.name,
            "projection": f"UTM zone {utm_zone_of(osm.origin.longitude_deg)}",
        },
    )
