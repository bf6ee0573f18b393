"""ScenarioNet's unified scenario format: one pickle per scenario, converted by ScenarioNet from
Waymo Open Motion, nuScenes, nuPlan, Argoverse 2, Lyft and others, so one reader reaches them all.

Pickles can run code when loaded; `load_pickle` admits only the classes the format uses (numpy
arrays and dtypes, builtin containers, `collections.defaultdict` / `OrderedDict`) and refuses any
other with one error naming the file and the class, before anything is built.

The local frame is the source's map frame shifted by a round offset near the recording car. The
WGS84 origin is known for nuScenes' four maps (their published origins); for other sources it is
nominal (0, 0), flagged in the map metadata. The format keeps a date but no clock time: the
start is set so that the sun stands for noon at the map's origin (`sun.start_time_for`).
nuScenes lanes carry (x, y, heading) rather than (x, y, z) and no widths: widths come from the
lane polygons, lanes without one are nuScenes' lane connectors (the junction), the map is flat
and boxes stand on it.
"""

from __future__ import annotations

import io
import math
import pickle
from collections.abc import Mapping
from dataclasses import replace
from datetime import date
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray
from pyproj import Transformer

from drivee2e_data.errors import ScenarioFormatError
from drivee2e_data.geometry import offset_polyline
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
    StaticObstacle,
    StopLine,
    TurnDirection,
)
from drivee2e_data.scenario import (
    AgentClass,
    Conditions,
    Scenario,
    SignalState,
    SignalTimeline,
    TimeOfDay,
    Weather,
)
from drivee2e_data.sources.argoverse2 import Imported
from drivee2e_data.sources.common import (
    ImportReport,
    grid_between,
    link_lanes_by_geometry,
    prune_lane_references,
    resample_track,
    turn_direction_of,
)
from drivee2e_data.sun import start_time_for

SOURCE = "scenarionet"
# (module, name) pairs a ScenarioNet pickle may name; numpy.core is numpy 1's path of numpy._core.
ALLOWED_GLOBALS = {
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "scalar"),
    ("collections", "defaultdict"),
    ("collections", "OrderedDict"),
    *(("builtins", name) for name in ("dict", "list", "tuple", "set", "frozenset")),
    *(("builtins", name) for name in ("int", "float", "str", "bool")),  # defaultdict factories
}
DATABASE_FILES = ("dataset_summary.pkl", "dataset_mapping.pkl")
REQUIRED_KEYS = ("id", "length", "metadata", "tracks", "map_features")
# nuScenes' published map origins (latitude, longitude of the map frame's (0, 0)).
NUSCENES_ORIGINS = {
    "boston-seaport": (42.336849169438615, -71.05785369873047),
    "singapore-onenorth": (1.2882100868743724, 103.78475189208984),
    "singapore-hollandvillage": (1.2993652317780957, 103.78217697143555),
    "singapore-queenstown": (1.2782562240223188, 103.76741409301758),
}
NOMINAL_DATE = date(2020, 6, 1)  # where the metadata has no date
# nuScenes categories (the tracks' `metadata.type`) onto our classes; the rest by ScenarioNet type.
NUSCENES_CLASSES = {
    "vehicle.car": AgentClass.CAR,
    "vehicle.emergency.police": AgentClass.CAR,
    "vehicle.emergency.ambulance": AgentClass.VAN,
    "vehicle.truck": AgentClass.TRUCK,
    "vehicle.trailer": AgentClass.TRUCK,
    "vehicle.construction": AgentClass.TRUCK,
    "vehicle.bus.rigid": AgentClass.BUS,
    "vehicle.bus.bendy": AgentClass.BUS,
    "vehicle.motorcycle": AgentClass.MOTORCYCLIST,
    "vehicle.bicycle": AgentClass.CYCLIST,
}
TYPE_CLASSES = {
    "VEHICLE": AgentClass.CAR,
    "PEDESTRIAN": AgentClass.PEDESTRIAN,
    "CYCLIST": AgentClass.CYCLIST,
    "MOTORCYCLIST": AgentClass.MOTORCYCLIST,
}
STATIC_TYPES = {"TRAFFIC_CONE": "cone", "TRAFFIC_BARRIER": "barrier"}
TRUCK_LENGTH_M = 6.5  # a generic VEHICLE at least this long is taken for a truck
PARKED_TRAVEL_M = 1.0  # a bicycle or motorcycle moving less than this has no rider
LIGHT_STATES = {
    "LANE_STATE_GO": SignalState.GREEN,
    "LANE_STATE_ARROW_GO": SignalState.GREEN,
    "LANE_STATE_CAUTION": SignalState.YELLOW,
    "LANE_STATE_ARROW_CAUTION": SignalState.YELLOW,
    "LANE_STATE_FLASHING_CAUTION": SignalState.YELLOW,
    "LANE_STATE_STOP": SignalState.RED,
    "LANE_STATE_ARROW_STOP": SignalState.RED,
    "LANE_STATE_FLASHING_STOP": SignalState.RED,
}
DEFAULT_LANE_WIDTH_M = 3.5
LANE_WIDTH_RANGE_M = (2.5, 5.0)
MARK_REACH_M = 0.75  # a road line this close to a lane boundary along most of it is its paint
SIGNAL_HEAD_HEIGHT_M = 5.0


class _RestrictedUnpickler(pickle.Unpickler):
    def __init__(self, stream: io.BufferedIOBase, path: Path) -> None:
        super().__init__(stream)
        self.path = path

    def find_class(self, module: str, name: str) -> Any:
        canonical = module.replace("numpy.core.", "numpy._core.")
        if (canonical, name) not in ALLOWED_GLOBALS:
            raise ScenarioFormatError(
                f"{self.path}: the pickle names {module}.{name}, which a ScenarioNet scenario "
                "never holds (only numpy arrays and builtin containers); refused, nothing was run"
            )
        return super().find_class(canonical, name)


def load_pickle(path: Path) -> Any:
    """A pickle's content, admitting only the classes of ScenarioNet's format."""
    path = Path(path)
    try:
        with path.open("rb") as stream:
            return _RestrictedUnpickler(stream, path).load()
    except ScenarioFormatError:
        raise
    except EOFError:
        raise ScenarioFormatError(f"{path}: truncated pickle (ended early)") from None
    except (pickle.UnpicklingError, ValueError, TypeError, AttributeError, IndexError) as error:
        if "truncated" in str(error):
            raise ScenarioFormatError(f"{path}: truncated pickle (ended early)") from None
        raise ScenarioFormatError(f"{path}: not a readable pickle ({error})") from None


def scenario_files(source: Path) -> list[Path]:
    """The scenario pickles of one file, a folder of them, or a ScenarioNet database folder
    (whose `dataset_mapping.pkl` maps each file name to the folder holding it)."""
    source = Path(source)
    if source.is_file():
        return [source]
    mapping_file = source / "dataset_mapping.pkl"
    if mapping_file.is_file():
        mapping = load_pickle(mapping_file)
        if not isinstance(mapping, Mapping):
            raise ScenarioFormatError(f"{mapping_file}: expected a dict of file name -> folder")
        files = [source / str(folder) / str(name) for name, folder in sorted(mapping.items())]
        missing = [f for f in files if not f.is_file()]
        if missing:
            raise ScenarioFormatError(f"{mapping_file}: lists {missing[0]}, which is missing")
        return files
    files = sorted(p for p in source.rglob("*.pkl") if p.name not in DATABASE_FILES)
    if not files:
        raise ScenarioFormatError(f"{source}: no ScenarioNet scenario (*.pkl)")
    return files


def import_scenario(path: Path) -> Imported:
    """One ScenarioNet scenario pickle as our map, scenario and import report."""
    path = Path(path)
    document = load_pickle(path)
    if not isinstance(document, Mapping):
        raise ScenarioFormatError(f"{path}: expected a dict, found {type(document).__name__}")
    for key in REQUIRED_KEYS:
        if key not in document:
            raise ScenarioFormatError(f"{path}: key {key!r} is missing")
    metadata = document["metadata"]
    dataset = str(metadata.get("dataset", "unknown"))
    scenario_id = f"scenarionet_{dataset}_{_safe(str(document['id']))}"
    times_s = _times(path, document)
    sdc_id = str(metadata.get("sdc_id", ""))
    offset = _offset(path, document, sdc_id)
    report = ImportReport()
    origin, origin_note = _origin(dataset, str(metadata.get("map", "")), offset)
    day = _date(metadata.get("date"))
    start = start_time_for(TimeOfDay.NOON, day, origin)
    t0_ns = int(start.timestamp()) * 1_000_000_000
    grid = grid_between(t0_ns, t0_ns + round(float(times_s[-1] - times_s[0]) * 1e9))
    source_ns = t0_ns + np.round((times_s - times_s[0]) * 1e9).astype(np.int64)
    flat = dataset == "nuscenes"
    intersection_map = _with_signal_heads(
        read_map(path, document, scenario_id, offset, origin, flat, report), document, offset
    )
    tracks, obstacles = [], []
    for track_id, entry in document["tracks"].items():
        result = _track(path, str(track_id), entry, offset, source_ns, grid, flat, report)
        if isinstance(result, StaticObstacle):
            obstacles.append(result)
        elif result is not None:
            tracks.append(result)
    signals = _signals(path, document, times_s, grid, intersection_map)
    intersection_map = replace(
        intersection_map,
        static_obstacles=tuple(obstacles),
        metadata={**intersection_map.metadata, "origin": origin_note},
    )
    ego = next((t for t in tracks if t.track_id == sdc_id), None)
    scenario = Scenario(
        scenario_id=scenario_id,
        map_id=intersection_map.map_id,
        source=SOURCE,
        t_ns=grid,
        tracks=tuple(tracks),
        signals=signals,
        conditions=Conditions(Weather.CLEAR, TimeOfDay.NOON, start),
        ego_id=sdc_id if ego is not None and ego.valid.all() else None,
        metadata={
            "source_file": path.name,
            "dataset": dataset,
            "source_scenario_id": str(document["id"]),
            "source_map": str(metadata.get("map", "")),
            "time and weather": "not in the format: clear, and the sun placed for noon on its date",
        },
    )
    return Imported(intersection_map, scenario, report)


def _safe(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in text)


def _times(path: Path, document: Mapping) -> NDArray[np.float64]:
    length = int(document["length"])
    times = document["metadata"].get("ts")
    if times is None:
        rate = float(document["metadata"].get("sample_rate", 0.1))
        return rate * np.arange(length, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64).ravel()
    if len(times) != length or not np.all(np.diff(times) > 0):
        raise ScenarioFormatError(
            f"{path}: metadata.ts must hold {length} increasing times (found {len(times)})"
        )
    return times


def _date(value: object) -> date:
    try:
        return date.fromisoformat(str(value)[:10])
    except ValueError:
        return NOMINAL_DATE


def _offset(path: Path, document: Mapping, sdc_id: str) -> NDArray[np.float64]:
    """A round (10 m) offset near the recording car, or near the tracks when it has none."""
    tracks = document["tracks"]
    entry = tracks.get(sdc_id) or next(iter(tracks.values()), None)
    if entry is None:
        raise ScenarioFormatError(f"{path}: 'tracks' is empty")
    position = _array(path, entry["state"], "position", f"tracks[{sdc_id!r}].state")
    valid = np.asarray(entry["state"]["valid"]).astype(bool).ravel()
    first = position[np.argmax(valid), :2] if valid.any() else position[0, :2]
    return np.append(np.round(first / 10.0) * 10.0, 0.0)


def _origin(dataset: str, map_name: str, offset: NDArray) -> tuple[GeoOrigin, str]:
    if dataset == "nuscenes" and map_name in NUSCENES_ORIGINS:
        latitude, longitude = NUSCENES_ORIGINS[map_name]
        local = Transformer.from_crs(
            f"+proj=aeqd +lat_0={latitude} +lon_0={longitude} +datum=WGS84 +units=m",
            "EPSG:4326",
            always_xy=True,
        )
        lon, lat = local.transform(float(offset[0]), float(offset[1]))
        return GeoOrigin(float(lat), float(lon)), f"nuScenes {map_name} origin plus the offset"
    return GeoOrigin(0.0, 0.0), "nominal (0, 0): the format gives no WGS84 origin"


def _array(path: Path, mapping: Mapping, key: str, where: str) -> NDArray[np.float64]:
    if key not in mapping:
        raise ScenarioFormatError(f"{path}: {where}.{key} is missing")
    try:
        values = np.asarray(mapping[key], dtype=np.float64)
    except (TypeError, ValueError):
        raise ScenarioFormatError(f"{path}: {where}.{key} is not numeric") from None
    return values


# ------------------------------------------------------------------------------------ tracks


def _track(
    path: Path,
    track_id: str,
    entry: Mapping,
    offset: NDArray,
    source_ns: NDArray[np.int64],
    grid: NDArray[np.int64],
    flat: bool,
    report: ImportReport,
):
    """A Track, a StaticObstacle (cones, barriers) or None (dropped, counted in the report)."""
    where = f"tracks[{track_id!r}].state"
    state = entry.get("state")
    if not isinstance(state, Mapping):
        raise ScenarioFormatError(f"{path}: {where} is missing")
    kind = str(entry.get("type", "UNKNOWN"))
    original = str((entry.get("metadata") or {}).get("type", kind))
    valid = np.asarray(state.get("valid", []), dtype=np.float64).ravel() > 0
    position = _array(path, state, "position", where)
    frames = len(source_ns)
    if len(valid) != frames or position.shape[0] != frames:
        raise ScenarioFormatError(
            f"{path}: {where} holds {position.shape[0]} positions and {len(valid)} valid flags, "
            f"expected {frames} (the scenario's length)"
        )
    if not valid.any():
        report.drop(original, "never valid")
        return None
    size = np.column_stack(
        [
            _array(path, state, key, where).reshape(frames, -1)[:, 0]
            for key in ("length", "width", "height")
        ]
    )
    heading = _array(path, state, "heading", where).reshape(frames, -1)[:, 0]
    xy = position[:, :2] - offset[:2]
    rows = np.flatnonzero(valid & np.isfinite(xy).all(axis=1) & np.isfinite(heading))
    travel = float(np.ptp(xy[rows], axis=0).max()) if len(rows) > 1 else 0.0
    if kind in STATIC_TYPES:
        middle = rows[len(rows) // 2]
        report.static[original] += 1
        return StaticObstacle(
            f"{STATIC_TYPES[kind]}_{_safe(track_id)}",
            STATIC_TYPES[kind],
            np.append(xy[middle], 0.5 * size[middle, 2]),
            float(heading[middle]),
            np.median(size[rows], axis=0),
        )
    agent_class = NUSCENES_CLASSES.get(original) or TYPE_CLASSES.get(kind)
    if original.startswith("human.pedestrian"):
        agent_class = AgentClass.PEDESTRIAN
    if agent_class is None:
        report.drop(original, "not one of the 8 classes")
        return None
    if agent_class in (AgentClass.CYCLIST, AgentClass.MOTORCYCLIST) and travel < PARKED_TRAVEL_M:
        report.drop(original, "parked two-wheeler (no rider)")
        return None
    if original == "VEHICLE" and np.median(size[rows, 0]) >= TRUCK_LENGTH_M:
        agent_class = AgentClass.TRUCK
    if agent_class.is_motor_vehicle:  # ScenarioNet's nuScenes ego swaps length and width
        short = size[:, 0] < size[:, 1]
        size[short, :2] = size[short, 1::-1]
    z = 0.5 * size[:, 2] if flat else position[:, 2] - offset[2]
    track = resample_track(
        track_id,
        agent_class,
        source_ns[rows],
        xy[rows],
        z[rows],
        heading[rows],
        size[rows],
        grid,
        {"source_class": original},
    )
    if track is None:
        report.drop(original, "no 10 Hz frame covered")
        return None
    report.keep(original, agent_class)
    return track


# ------------------------------------------------------------------------------------ map


def read_map(
    path: Path,
    document: Mapping,
    map_id: str,
    offset: NDArray,
    origin: GeoOrigin,
    flat: bool,
    report: ImportReport,
) -> IntersectionMap:
    """The scenario's map features as an `IntersectionMap` in the local frame."""
    features = document["map_features"]
    lanes, kept_polygons, road_lines, kerbs, crosswalks, stop_signs = [], [], [], [], [], []
    ignored: dict[str, int] = {}
    unknown_width: set[str] = set()
    for feature_id, feature in features.items():
        kind = str(feature.get("type", ""))
        key = str(feature_id)
        where = f"map_features[{key!r}]"
        if kind.startswith("LANE_"):
            lane, polygon, known = _lane(path, key, feature, offset, flat, where)
            if lane is not None:
                lanes.append(lane)
                if not known:
                    unknown_width.add(key)
            if polygon is not None:
                kept_polygons.append(polygon)
        elif kind.startswith("ROAD_LINE_"):
            road_lines.append((_line(path, feature, offset, where), _mark_of(kind)))
        elif kind.startswith("ROAD_EDGE_"):
            kerbs.append(Kerb(f"edge_{_safe(key)}", _line(path, feature, offset, where)))
        elif kind == "CROSSWALK":
            polygon = _array(path, feature, "polygon", where)[:, :2] - offset[:2]
            crosswalks.append(Crosswalk(f"crosswalk_{_safe(key)}", polygon))
        elif kind == "STOP_SIGN":
            stop_signs.append((key, feature))
        else:
            ignored[kind] = ignored.get(kind, 0) + 1
    if not lanes:
        raise ScenarioFormatError(f"{path}: map_features holds no lane (LANE_*)")
    lanes = _with_topology(lanes)
    lanes = prune_lane_references(lanes, path.name, report)
    lanes = _with_widths_from_neighbours(lanes, unknown_width)
    lanes = _with_marks(lanes, road_lines)
    stop_lines = [_stop_sign_line(key, feature, lanes, offset) for key, feature in stop_signs]
    road = shapely.union_all([*kept_polygons, *(lane.polygon() for lane in lanes)])
    parts = [p for p in getattr(road, "geoms", [road]) if isinstance(p, shapely.Polygon)]
    areas = tuple(
        Area(f"road_{k}", np.asarray(p.exterior.coords)[:-1, :2])
        for k, p in enumerate(parts)
        if p.area > 1.0
    )
    return IntersectionMap(
        map_id=map_id,
        origin=origin,
        lanes=tuple(lanes),
        crosswalks=tuple(crosswalks),
        stop_lines=tuple(s for s in stop_lines if s is not None),
        drivable_areas=areas,
        kerbs=tuple(kerbs),
        metadata={
            "source": SOURCE,
            "offset_m": offset.tolist(),
            "lane marks": "from the nearest road line along each lane boundary",
            "features not modelled": dict(sorted(ignored.items())),
        },
    )


def _line(path: Path, feature: Mapping, offset: NDArray, where: str) -> NDArray[np.float64]:
    points = _array(path, feature, "polyline", where)
    if points.ndim != 2 or points.shape[0] < 2 or points.shape[1] < 2:
        raise ScenarioFormatError(f"{path}: {where}.polyline must be (N >= 2, 2 or 3) points")
    return np.column_stack([points[:, :2] - offset[:2], np.zeros(len(points))])


def _lane(
    path: Path, key: str, feature: Mapping, offset: NDArray, flat: bool, where: str
) -> tuple[Lane | None, shapely.Geometry | None, bool]:
    """The lane, its source polygon if any, and whether its width is known."""
    points = _array(path, feature, "polyline", where)
    if points.ndim != 2 or points.shape[1] < 2:
        raise ScenarioFormatError(f"{path}: {where}.polyline must be (N, 2 or 3) points")
    keep = np.ones(len(points), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(points[:, :2], axis=0), axis=1) > 1e-3
    points = points[keep]
    if len(points) < 2:
        return None, None, False
    z = np.zeros(len(points)) if flat or points.shape[1] < 3 else points[:, 2] - offset[2]
    centre = np.column_stack([points[:, :2] - offset[:2], z])
    polygon = None
    if feature.get("polygon") is not None and len(feature["polygon"]) >= 3:
        ring = _array(path, feature, "polygon", where)[:, :2] - offset[:2]
        polygon = shapely.make_valid(shapely.Polygon(ring))
    half_left, half_right = _half_widths(feature, centre, polygon)
    known = math.isfinite(half_right)
    half_right = half_right if known else half_left
    kind = str(feature["type"])
    # nuScenes: lanes carry a polygon, the lane connectors across the junction none
    in_junction = flat and polygon is None
    lane = Lane(
        lane_id=key,
        centerline_m=centre,
        left_boundary_m=np.column_stack([offset_polyline(centre, half_left), z]),
        right_boundary_m=np.column_stack([offset_polyline(centre, -half_right), z]),
        lane_type=LaneType.BIKE if kind == "LANE_BIKE_LANE" else LaneType.VEHICLE,
        is_intersection=in_junction,
        turn_direction=turn_direction_of(centre) if in_junction else TurnDirection.NONE,
        predecessors=_ids(feature.get("entry_lanes")),
        successors=_ids(feature.get("exit_lanes")),
        left_neighbor=next(iter(_ids(feature.get("left_neighbor"))), None),
        right_neighbor=next(iter(_ids(feature.get("right_neighbor"))), None),
        speed_limit_mps=_speed(feature),
    )
    return lane, polygon, known


def _ids(values: Any) -> tuple[str, ...]:
    """Lane ids from a list of ids or of neighbour records ({'feature_id': ...} / {'id': ...})."""
    if values is None:
        return ()
    if isinstance(values, (str, int, np.integer)):
        values = [values]
    ids = []
    for value in values:
        if isinstance(value, Mapping):
            value = value.get("feature_id", value.get("id"))
        if value is not None:
            ids.append(str(value))
    return tuple(ids)


def _speed(feature: Mapping) -> float | None:
    if feature.get("speed_limit_mph") is not None:
        return float(feature["speed_limit_mph"]) * 0.44704
    if feature.get("speed_limit_kmh") is not None:
        return float(feature["speed_limit_kmh"]) / 3.6
    return None


def _half_widths(
    feature: Mapping, centre: NDArray, polygon: shapely.Geometry | None
) -> tuple[float, float]:
    """Half widths to the left and right: the lane's `width` ((N, 2) left/right or a full
    width), else twice the median distance from the centerline to the lane polygon's edge,
    else the default on the left and NaN on the right (the width is taken from the lanes
    it joins later); clipped to 2.5-5 m in all."""
    low, high = LANE_WIDTH_RANGE_M
    width = feature.get("width")
    if width is not None:
        values = np.asarray(width, dtype=np.float64)
        if values.ndim == 2 and values.shape[1] == 2 and np.isfinite(values).all():
            left, right = np.median(values, axis=0)
            return float(np.clip(left, low / 2, high / 2)), float(np.clip(right, low / 2, high / 2))
        if values.size and np.isfinite(values).all():
            full = float(np.clip(np.median(values), low, high))
            return full / 2, full / 2
    if polygon is not None and not polygon.is_empty:
        edge = polygon.boundary
        distance = shapely.distance(edge, shapely.points(centre[:, :2]))
        full = float(np.clip(2.0 * np.median(distance), low, high))
        return full / 2, full / 2
    return DEFAULT_LANE_WIDTH_M / 2, math.nan  # NaN on the right: the width is not known


def _with_topology(lanes: list[Lane]) -> list[Lane]:
    """The file's entry/exit lanes where it has them, else links from geometry."""
    if any(lane.predecessors or lane.successors for lane in lanes):
        return lanes
    return link_lanes_by_geometry(lanes)


def _with_widths_from_neighbours(lanes: list[Lane], unknown: set[str]) -> list[Lane]:
    """Lanes without a width (nuScenes lane connectors) take the mean of the lanes they join,
    or the default; their boundaries are rebuilt."""
    by_id = {lane.lane_id: lane for lane in lanes}

    def width(lane: Lane) -> float:
        return float(np.linalg.norm(lane.left_boundary_m[0, :2] - lane.right_boundary_m[0, :2]))

    result = []
    for lane in lanes:
        if lane.lane_id not in unknown:
            result.append(lane)
            continue
        joined = [by_id[i] for i in (*lane.predecessors, *lane.successors)]
        widths = [width(j) for j in joined if j.lane_id not in unknown]
        half = (float(np.mean(widths)) if widths else DEFAULT_LANE_WIDTH_M) / 2
        centre = lane.centerline_m
        result.append(
            replace(
                lane,
                left_boundary_m=np.column_stack([offset_polyline(centre, half), centre[:, 2]]),
                right_boundary_m=np.column_stack([offset_polyline(centre, -half), centre[:, 2]]),
            )
        )
    return result


def _mark_of(kind: str) -> LaneMark:
    """ROAD_LINE_{BROKEN,SOLID,PASSING}_{SINGLE,DOUBLE}_{WHITE,YELLOW} as a lane mark."""
    words = kind.removeprefix("ROAD_LINE_").split("_")
    colour = MarkColour.YELLOW if "YELLOW" in words else MarkColour.WHITE
    double = "DOUBLE" in words
    if "PASSING" in words:
        pattern = MarkPattern.SOLID_DASHED
    elif "BROKEN" in words:
        pattern = MarkPattern.DOUBLE_DASHED if double else MarkPattern.DASHED
    elif "SOLID" in words:
        pattern = MarkPattern.DOUBLE_SOLID if double else MarkPattern.SOLID
    else:  # ROAD_LINE_UNKNOWN
        pattern = MarkPattern.SOLID
    return LaneMark(pattern, colour)


def _with_marks(lanes: list[Lane], road_lines: list[tuple[NDArray, LaneMark]]) -> list[Lane]:
    """Each boundary of a lane outside the junction takes the mark of the road line lying
    within 0.75 m of it along at least half its length; junction lanes stay unpainted."""
    if not road_lines:
        return lanes
    geometries = [shapely.LineString(line[:, :2]) for line, _ in road_lines]
    tree = shapely.STRtree(geometries)

    def mark(boundary: NDArray) -> LaneMark:
        line = shapely.LineString(boundary[:, :2])
        samples = shapely.line_interpolate_point(
            line, np.linspace(0.0, line.length, max(3, int(line.length)))
        )
        nearest, distance = tree.query_nearest(samples, return_distance=True, all_matches=False)
        close = nearest[1][distance <= MARK_REACH_M]
        if len(close) * 2 < len(samples):
            return LaneMark()
        return road_lines[int(np.bincount(close).argmax())][1]

    return [
        lane
        if lane.is_intersection
        else replace(
            lane, left_mark=mark(lane.left_boundary_m), right_mark=mark(lane.right_boundary_m)
        )
        for lane in lanes
    ]


def _stop_sign_line(
    key: str, feature: Mapping, lanes: list[Lane], offset: NDArray
) -> StopLine | None:
    """A stop sign's stop line: across each lane it controls, at the point nearest the sign."""
    position = feature.get("position")
    controlled = [lane for lane in lanes if lane.lane_id in set(_ids(feature.get("lane")))]
    if position is None or not controlled:
        return None
    point = shapely.Point(np.asarray(position, dtype=np.float64)[:2] - offset[:2])
    return StopLine(
        f"stop_sign_{_safe(key)}",
        _across(controlled[0], point),
        tuple(lane.lane_id for lane in controlled),
    )


def _across(lane: Lane, point: shapely.Point) -> NDArray[np.float64]:
    """`(2, 3)` a line across `lane` from its left to its right boundary, at the point of its
    centre line nearest `point` (on the ground)."""
    along = shapely.LineString(lane.centerline_m[:, :2]).project(point)
    left = shapely.LineString(lane.left_boundary_m[:, :2]).interpolate(along)
    right = shapely.LineString(lane.right_boundary_m[:, :2]).interpolate(along)
    return np.array([[left.x, left.y, 0.0], [right.x, right.y, 0.0]])


# ------------------------------------------------------------------------------------ lights


def _signals(
    path: Path,
    document: Mapping,
    times_s: NDArray[np.float64],
    grid: NDArray[np.int64],
    intersection_map: IntersectionMap,
) -> tuple[SignalTimeline, ...]:
    """Traffic-light states per controlled lane, onto the 10 Hz grid (nearest source frame)."""
    states = document.get("dynamic_map_states") or {}
    if not states:
        return ()
    lane_ids = {lane.lane_id for lane in intersection_map.lanes}
    offsets_s = times_s - times_s[0]
    right = np.clip(np.searchsorted(offsets_s, (grid - grid[0]) / 1e9), 1, len(times_s) - 1)
    nearer_left = (grid - grid[0]) / 1e9 - offsets_s[right - 1] < offsets_s[right] - (
        grid - grid[0]
    ) / 1e9
    frame_of = np.where(nearer_left, right - 1, right)
    timelines = []
    for key, entry in states.items():
        lane = str(entry.get("lane", ""))
        if lane not in lane_ids:
            continue
        names = list((entry.get("state") or {}).get("object_state") or [])
        if len(names) != len(times_s):
            raise ScenarioFormatError(
                f"{path}: dynamic_map_states[{key!r}].state.object_state holds {len(names)} "
                f"states, expected {len(times_s)}"
            )
        codes = np.array(
            [LIGHT_STATES.get(str(names[k]), SignalState.UNKNOWN).value for k in frame_of],
            np.uint8,
        )
        timelines.append(SignalTimeline(f"light_{_safe(str(key))}", codes, origin="recorded"))
    return tuple(timelines)


def _with_signal_heads(
    intersection_map: IntersectionMap, document: Mapping, offset: NDArray
) -> IntersectionMap:
    """The map with a signal head and a stop line at each light's stop point, and the
    controlled lanes pointing at their light."""
    states = document.get("dynamic_map_states") or {}
    lanes = {lane.lane_id: lane for lane in intersection_map.lanes}
    heads, stop_lines = list(intersection_map.signal_heads), list(intersection_map.stop_lines)
    for key, entry in states.items():
        lane_id = str(entry.get("lane", ""))
        if lane_id not in lanes or entry.get("stop_point") is None:
            continue
        signal_id = f"light_{_safe(str(key))}"
        lane = lanes[lane_id]
        stop = np.asarray(entry["stop_point"], dtype=np.float64)[:2] - offset[:2]
        back = lane.centerline_m[0, :2] - lane.centerline_m[-1, :2]
        heads.append(
            SignalHead(
                f"head_{signal_id}",
                signal_id,
                np.append(stop, SIGNAL_HEAD_HEIGHT_M),
                float(np.arctan2(back[1], back[0])),
                controlled_lane_ids=(lane_id,),
            )
        )
        stop_lines.append(
            StopLine(f"stop_{signal_id}", _across(lane, shapely.Point(stop)), (lane_id,))
        )
        lanes[lane_id] = replace(lane, signal_id=signal_id)
    return replace(
        intersection_map,
        lanes=tuple(lanes.values()),
        signal_heads=tuple(heads),
        stop_lines=tuple(stop_lines),
    )
