"""Argoverse 2: sensor-dataset logs (cuboid tracks around a recording car) and motion-forecasting
scenarios, with their vector maps.

The local frame is the AV2 city frame shifted by a round offset near the recording, so numbers
stay small; the map's WGS84 origin is that offset placed through the city's published origin and
UTM zone. AV2 records neither weather nor signal states: conditions default to clear (flagged
in the scenario metadata) and there are no signal timelines. Stop lines are derived where a lane
enters the intersection, and flagged as derived.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
import pyarrow.parquet as pq
import shapely
from numpy.typing import NDArray

from drivee2e_data.errors import ScenarioFormatError
from drivee2e_data.geometry import (
    centerline_between,
    rotation_from_quaternion,
    yaw_from_quaternion,
)
from drivee2e_data.hdmap import (
    Area,
    Crosswalk,
    IntersectionMap,
    Lane,
    LaneMark,
    LaneType,
    MarkColour,
    MarkPattern,
    StaticObstacle,
    StopLine,
    TurnDirection,
)
from drivee2e_data.scenario import FRAME_PERIOD_NS, AgentClass, Conditions, Scenario, Track, Weather
from drivee2e_data.sources.common import (
    TYPICAL_SIZE_M,
    ImportReport,
    geo_origin_of_utm,
    grid_between,
    prune_lane_references,
    resample_track,
    turn_direction_of,
    utc_from_ns,
    utm_transformer,
)
from drivee2e_data.sun import time_of_day_of

SOURCE = "argoverse2"
# Published AV2 city origins (latitude, longitude of the city frame's (0, 0)) and UTM zones.
CITY_ORIGIN = {
    "ATX": (30.27464237939507, -97.7404457407424, 14),
    "DTW": (42.29993066912924, -83.17555750783717, 17),
    "MIA": (25.77452579915163, -80.19656914449405, 17),
    "PAO": (37.416065, -122.13571963362166, 10),
    "PIT": (40.44177902989321, -80.01294377242584, 17),
    "WDC": (38.889377, -77.0355047439081, 18),
}
CITY_NAMES = {
    "austin": "ATX",
    "dearborn": "DTW",
    "miami": "MIA",
    "palo-alto": "PAO",
    "pittsburgh": "PIT",
    "washington-dc": "WDC",
}
# The recording car (a Ford Fusion Hybrid): box size, and how far its box centre sits ahead of
# the rear-axle origin of the AV2 ego-vehicle frame (half the 2.85 m wheelbase, approximately).
RECORDING_CAR_SIZE_M = (4.87, 1.85, 1.48)
REAR_AXLE_TO_CENTRE_M = 1.42
RECORDING_CAR_ID = "av2_recording_car"
MAP_REACH_M = 2.0  # track frames farther than this from the drivable area and crosswalks are cut
STATIC_TRAVEL_M = 1.0  # an object moving less than this over the log is static

# Sensor-dataset categories onto our classes; None: not an agent (see STATIC_KINDS / dropped).
SENSOR_CLASSES: dict[str, AgentClass | None] = {
    "REGULAR_VEHICLE": AgentClass.CAR,
    "LARGE_VEHICLE": AgentClass.VAN,
    "BOX_TRUCK": AgentClass.TRUCK,
    "TRUCK": AgentClass.TRUCK,
    "TRUCK_CAB": AgentClass.TRUCK,
    "BUS": AgentClass.BUS,
    "SCHOOL_BUS": AgentClass.BUS,
    "ARTICULATED_BUS": AgentClass.BUS,
    "PEDESTRIAN": AgentClass.PEDESTRIAN,
    "OFFICIAL_SIGNALER": AgentClass.PEDESTRIAN,
    "WHEELED_RIDER": AgentClass.CYCLIST,
    "BICYCLE": AgentClass.CYCLIST,  # when moving; the bicycle's cuboid carries the cyclist
    "MOTORCYCLE": AgentClass.MOTORCYCLIST,  # when moving, likewise
}
STATIC_KINDS = {
    "BOLLARD",
    "CONSTRUCTION_CONE",
    "CONSTRUCTION_BARREL",
    "SIGN",
    "STOP_SIGN",
    "MESSAGE_BOARD_TRAILER",
    "MOBILE_PEDESTRIAN_CROSSING_SIGN",
    "TRAFFIC_LIGHT_TRAILER",
    "STROLLER",
    "WHEELCHAIR",
    "WHEELED_DEVICE",
    "BICYCLE",
    "MOTORCYCLE",
    "VEHICULAR_TRAILER",
}
DROP_REASONS = {
    "BICYCLIST": "rider of a BICYCLE cuboid, which carries the cyclist",
    "MOTORCYCLIST": "rider of a MOTORCYCLE cuboid, which carries the motorcyclist",
    "VEHICULAR_TRAILER": "moving trailer of an articulated truck whose cab is kept",
    "DOG": "animal, not one of the 8 classes",
    "ANIMAL": "animal, not one of the 8 classes",
}
FORECAST_CLASSES = {
    "vehicle": AgentClass.CAR,
    "bus": AgentClass.BUS,
    "pedestrian": AgentClass.PEDESTRIAN,
    "cyclist": AgentClass.CYCLIST,
    "motorcyclist": AgentClass.MOTORCYCLIST,
}
MARKS = {
    "NONE": LaneMark(),
    "UNKNOWN": LaneMark(),
    "SOLID_WHITE": LaneMark(MarkPattern.SOLID, MarkColour.WHITE),
    "SOLID_YELLOW": LaneMark(MarkPattern.SOLID, MarkColour.YELLOW),
    "SOLID_BLUE": LaneMark(MarkPattern.SOLID, MarkColour.BLUE),
    "DASHED_WHITE": LaneMark(MarkPattern.DASHED, MarkColour.WHITE),
    "DASHED_YELLOW": LaneMark(MarkPattern.DASHED, MarkColour.YELLOW),
    "DOUBLE_SOLID_WHITE": LaneMark(MarkPattern.DOUBLE_SOLID, MarkColour.WHITE),
    "DOUBLE_SOLID_YELLOW": LaneMark(MarkPattern.DOUBLE_SOLID, MarkColour.YELLOW),
    "DOUBLE_DASH_WHITE": LaneMark(MarkPattern.DOUBLE_DASHED, MarkColour.WHITE),
    "DOUBLE_DASH_YELLOW": LaneMark(MarkPattern.DOUBLE_DASHED, MarkColour.YELLOW),
    "DASH_SOLID_WHITE": LaneMark(MarkPattern.DASHED_SOLID, MarkColour.WHITE),
    "DASH_SOLID_YELLOW": LaneMark(MarkPattern.DASHED_SOLID, MarkColour.YELLOW),
    "SOLID_DASH_WHITE": LaneMark(MarkPattern.SOLID_DASHED, MarkColour.WHITE),
    "SOLID_DASH_YELLOW": LaneMark(MarkPattern.SOLID_DASHED, MarkColour.YELLOW),
}


@dataclass(frozen=True)
class Imported:
    intersection_map: IntersectionMap
    scenario: Scenario
    report: ImportReport


@dataclass(frozen=True)
class LocalFrame:
    """City coordinates minus `offset_m` (x, y, z) are the local frame's."""

    city: str
    offset_m: NDArray[np.float64]

    def to_local(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        return points - self.offset_m[: points.shape[-1]]


# ------------------------------------------------------------------------------ maps


def _points(value: Any, where: str) -> NDArray[np.float64]:
    try:
        return np.array([[p["x"], p["y"], p.get("z", 0.0)] for p in value], dtype=np.float64)
    except (TypeError, KeyError) as error:
        raise ScenarioFormatError(
            f"{where}: expected a list of {{x, y, z}} points ({error})"
        ) from None


def _ids(values: Any) -> tuple[str, ...]:
    return tuple(str(value) for value in (values or []))


def _id(value: Any) -> str | None:
    return None if value is None else str(value)


def read_map(path: Path, frame: LocalFrame, map_id: str, report: ImportReport) -> IntersectionMap:
    """An AV2 `log_map_archive_*.json` in the local frame."""
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ScenarioFormatError(f"{path}: not a readable JSON map ({error})") from None
    for key in ("lane_segments", "pedestrian_crossings", "drivable_areas"):
        if key not in document:
            raise ScenarioFormatError(f"{path}: key {key!r} is missing")
    segments = document["lane_segments"]
    lanes = []
    for key, segment in segments.items():
        where = f"{path} lane_segments[{key}]"
        left = frame.to_local(_points(segment["left_lane_boundary"], f"{where}.left_lane_boundary"))
        right = frame.to_local(
            _points(segment["right_lane_boundary"], f"{where}.right_lane_boundary")
        )
        centre = centerline_between(left, right)

        for side in ("left_lane_mark_type", "right_lane_mark_type"):
            if segment[side] not in MARKS:
                raise ScenarioFormatError(f"{where}.{side}: unknown mark type {segment[side]!r}")
        is_intersection = bool(segment["is_intersection"])
        lanes.append(
            Lane(
                lane_id=str(segment["id"]),
                centerline_m=centre,
                left_boundary_m=left,
                right_boundary_m=right,
                left_mark=MARKS[segment["left_lane_mark_type"]],
                right_mark=MARKS[segment["right_lane_mark_type"]],
                lane_type=LaneType(segment["lane_type"].lower()),
                turn_direction=turn_direction_of(centre) if is_intersection else TurnDirection.NONE,
                is_intersection=is_intersection,
                predecessors=_ids(segment.get("predecessors")),
                successors=_ids(segment.get("successors")),
                left_neighbor=_id(segment.get("left_neighbor_id")),
                right_neighbor=_id(segment.get("right_neighbor_id")),
            )
        )
    lanes = prune_lane_references(lanes, path.name, report)
    crosswalks = tuple(
        Crosswalk(
            str(c["id"]),
            np.concatenate(
                [
                    frame.to_local(_points(c["edge1"], f"{path} crosswalk {k}"))[:, :2],
                    frame.to_local(_points(c["edge2"], f"{path} crosswalk {k}"))[::-1, :2],
                ]
            ),
        )
        for k, c in document["pedestrian_crossings"].items()
    )
    areas = tuple(
        Area(
            f"drivable_{a['id']}",
            frame.to_local(_points(a["area_boundary"], f"{path} area {k}"))[:, :2],
        )
        for k, a in document["drivable_areas"].items()
    )
    lane_by_id = {lane.lane_id: lane for lane in lanes}
    stop_lines = tuple(
        StopLine(
            f"stop_{lane.lane_id}",
            np.stack([lane.left_boundary_m[-1], lane.right_boundary_m[-1]]),
            (lane.lane_id,),
            derived=True,
        )
        for lane in lanes
        if not lane.is_intersection
        and lane.lane_type == LaneType.VEHICLE
        and any(lane_by_id[s].is_intersection for s in lane.successors)
    )
    return IntersectionMap(
        map_id=map_id,
        origin=_origin(frame),
        lanes=tuple(lanes),
        crosswalks=crosswalks,
        stop_lines=stop_lines,
        drivable_areas=areas,
        metadata={
            "source": SOURCE,
            "city": frame.city,
            "city_offset_m": frame.offset_m.tolist(),
            "stop_lines": "derived where lanes enter the intersection",
        },
    )


def _origin(frame: LocalFrame):
    latitude, longitude, zone = CITY_ORIGIN[frame.city]
    easting, northing = utm_transformer(zone).transform(longitude, latitude)
    return geo_origin_of_utm(
        easting + frame.offset_m[0], northing + frame.offset_m[1], zone, float(frame.offset_m[2])
    )


def _map_file(folder: Path) -> Path:
    candidates = sorted(folder.glob("log_map_archive_*.json"))
    if not candidates:
        raise ScenarioFormatError(f"{folder}: no log_map_archive_*.json map file")
    return candidates[0]


def _city_of_map(path: Path) -> str | None:
    for code in CITY_ORIGIN:
        if f"__{code}_" in path.name or f"____{code}" in path.name:
            return code
    return None


def _map_reach(intersection_map: IntersectionMap) -> shapely.Geometry:
    pieces = [shapely.Polygon(a.polygon_m) for a in intersection_map.drivable_areas]
    pieces += [shapely.Polygon(c.polygon_m) for c in intersection_map.crosswalks]
    return shapely.union_all([shapely.make_valid(p) for p in pieces]).buffer(MAP_REACH_M)


def _clip_to_map(track: Track, reach: shapely.Geometry) -> Track | None:
    inside = (
        shapely.contains_xy(reach, np.nan_to_num(track.x_m), np.nan_to_num(track.y_m)) & track.valid
    )
    if not inside.any():
        return None
    if inside.all() or np.array_equal(inside, track.valid):
        return track
    return replace(track, valid=inside)


# ------------------------------------------------------------------------------ sensor logs


def _read_feather(path: Path, columns: list[str]) -> pa.Table:
    if not path.is_file():
        raise ScenarioFormatError(f"{path}: file is missing")
    try:
        table = feather.read_table(path)
    except (pa.ArrowException, OSError) as error:
        raise ScenarioFormatError(f"{path}: not a readable Feather file ({error})") from None
    for column in columns:
        if column not in table.column_names:
            raise ScenarioFormatError(f"{path}: column {column!r} is missing")
    return table


POSE_COLUMNS = ["timestamp_ns", "qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m"]


def import_sensor_log(folder: Path) -> Imported:
    """A sensor-dataset log folder: `annotations.feather`, `city_SE3_egovehicle.feather`, `map/`."""
    folder = Path(folder)
    report = ImportReport()
    poses = _read_feather(folder / "city_SE3_egovehicle.feather", POSE_COLUMNS)
    annotations = _read_feather(
        folder / "annotations.feather",
        [*POSE_COLUMNS, "track_uuid", "category", "length_m", "width_m", "height_m"],
    )
    map_file = _map_file(folder / "map")
    city = _city_of_map(map_file)
    if city is None:
        raise ScenarioFormatError(f"{map_file}: cannot tell the city from the file name")
    pose_t = poses.column("timestamp_ns").to_numpy()
    order = np.argsort(pose_t)
    pose_t = pose_t[order]
    pose_q = np.stack([poses.column(c).to_numpy()[order] for c in ("qw", "qx", "qy", "qz")], -1)
    pose_xyz = np.stack([poses.column(c).to_numpy()[order] for c in ("tx_m", "ty_m", "tz_m")], -1)
    frame = LocalFrame(city, np.round(pose_xyz.mean(axis=0), 0))
    log_id = folder.name
    intersection_map = read_map(map_file, frame, f"av2_{log_id}", report)

    stamps = np.unique(annotations.column("timestamp_ns").to_numpy())
    grid = grid_between(int(stamps[0]), int(stamps[-1]))
    rotation_city_ego = rotation_from_quaternion(pose_q)
    tracks: list[Track] = []
    obstacles: list[StaticObstacle] = []

    ego_centre = pose_xyz + REAR_AXLE_TO_CENTRE_M * rotation_city_ego[:, :, 0]
    ego_centre[:, 2] += 0.5 * RECORDING_CAR_SIZE_M[2]
    within = (pose_t >= grid[0] - FRAME_PERIOD_NS) & (pose_t <= grid[-1] + FRAME_PERIOD_NS)
    ego_track = resample_track(
        RECORDING_CAR_ID,
        AgentClass.CAR,
        pose_t[within],
        frame.to_local(ego_centre[within])[:, :2],
        frame.to_local(ego_centre[within])[:, 2],
        yaw_from_quaternion(pose_q[within]),
        np.tile(RECORDING_CAR_SIZE_M, (int(within.sum()), 1)),
        grid,
        {
            "role": "recording car",
            "rear_axle_to_centre_m": str(REAR_AXLE_TO_CENTRE_M),
            "size_source": "vehicle model (Ford Fusion Hybrid)",
        },
    )
    if ego_track is not None:
        tracks.append(ego_track)
        report.keep("RECORDING_CAR", AgentClass.CAR)

    uuids = np.asarray(annotations.column("track_uuid").to_pylist(), dtype=object)
    categories = annotations.column("category").to_pylist()
    t = annotations.column("timestamp_ns").to_numpy()
    q = np.stack([annotations.column(c).to_numpy() for c in ("qw", "qx", "qy", "qz")], -1)
    xyz = np.stack([annotations.column(c).to_numpy() for c in ("tx_m", "ty_m", "tz_m")], -1)
    size = np.stack(
        [annotations.column(c).to_numpy() for c in ("length_m", "width_m", "height_m")], -1
    )
    pose_index = np.searchsorted(pose_t, t)
    exact = (pose_index < len(pose_t)) & (pose_t[np.minimum(pose_index, len(pose_t) - 1)] == t)
    if not exact.all():
        row = int(np.flatnonzero(~exact)[0])
        raise ScenarioFormatError(
            f"{folder / 'annotations.feather'} row {row}: timestamp_ns {t[row]} has no ego pose in "
            "city_SE3_egovehicle.feather"
        )
    rotation = rotation_city_ego[pose_index]
    city_xyz = np.einsum("nij,nj->ni", rotation, xyz) + pose_xyz[pose_index]
    city_yaw = yaw_from_quaternion(q) + yaw_from_quaternion(pose_q[pose_index])
    local = frame.to_local(city_xyz)
    reach = _map_reach(intersection_map)
    for uuid in dict.fromkeys(uuids.tolist()):
        rows = np.flatnonzero(uuids == uuid)
        rows = rows[np.argsort(t[rows])]
        category = categories[rows[0]]
        travel = float(np.ptp(local[rows, :2], axis=0).max()) if len(rows) > 1 else 0.0
        agent_class = SENSOR_CLASSES.get(category)
        moving = travel >= STATIC_TRAVEL_M
        if category in ("BICYCLE", "MOTORCYCLE", "VEHICULAR_TRAILER") and not moving:
            agent_class = None
        if agent_class is None or (category == "VEHICULAR_TRAILER"):
            if category in STATIC_KINDS and not moving:
                middle = rows[len(rows) // 2]
                obstacles.append(
                    StaticObstacle(
                        f"{category.lower()}_{len(obstacles):03d}",
                        category.lower(),
                        local[middle],
                        float(city_yaw[middle]),
                        np.median(size[rows], axis=0),
                    )
                )
                report.static[category] += 1
            else:
                report.drop(
                    category, DROP_REASONS.get(category, "moving object outside the 8 classes")
                )
            continue
        track = resample_track(
            uuid,
            agent_class,
            t[rows],
            local[rows, :2],
            local[rows, 2],
            city_yaw[rows],
            size[rows],
            grid,
            {"source_class": category},
        )
        track = None if track is None else _clip_to_map(track, reach)
        if track is None:
            report.drop(
                category, "outside the mapped area (more than 2 m from road and crosswalks)"
            )
            continue
        tracks.append(track)
        report.keep(category, agent_class)
    intersection_map = _with_obstacles(intersection_map, obstacles)
    start = utc_from_ns(int(grid[0]))
    scenario = Scenario(
        scenario_id=f"av2_{log_id}",
        map_id=intersection_map.map_id,
        source=SOURCE,
        t_ns=grid,
        tracks=tuple(tracks),
        signals=(),
        conditions=Conditions(Weather.CLEAR, time_of_day_of(start, intersection_map.origin), start),
        ego_id=RECORDING_CAR_ID if ego_track is not None and ego_track.valid.all() else None,
        metadata={
            "source_folder": folder.name,
            "kind": "sensor log",
            "weather": "not recorded; clear assumed",
            "signals": "not recorded",
        },
    )
    return Imported(intersection_map, scenario, report)


def _with_obstacles(
    intersection_map: IntersectionMap, obstacles: list[StaticObstacle]
) -> IntersectionMap:
    return replace(intersection_map, static_obstacles=tuple(obstacles))


# ------------------------------------------------------------------------------ forecasting


FORECAST_COLUMNS = [
    "track_id",
    "object_type",
    "timestep",
    "position_x",
    "position_y",
    "heading",
    "start_timestamp",
    "city",
]


def import_forecasting(folder: Path) -> Imported:
    """A motion-forecasting scenario folder: `scenario_*.parquet` and `log_map_archive_*.json`."""
    folder = Path(folder)
    report = ImportReport()
    files = sorted(folder.glob("scenario_*.parquet"))
    if not files:
        raise ScenarioFormatError(f"{folder}: no scenario_*.parquet file")
    path = files[0]
    try:
        table = pq.read_table(path)
    except (pa.ArrowException, OSError) as error:
        raise ScenarioFormatError(f"{path}: not a readable Parquet file ({error})") from None
    for column in FORECAST_COLUMNS:
        if column not in table.column_names:
            raise ScenarioFormatError(f"{path}: column {column!r} is missing")
    city_name = table.column("city")[0].as_py()
    if city_name not in CITY_NAMES:
        raise ScenarioFormatError(
            f"{path} row 0: column 'city' is {city_name!r}, expected one of {sorted(CITY_NAMES)}"
        )
    ids = np.asarray(table.column("track_id").to_pylist(), dtype=object)
    kinds = table.column("object_type").to_pylist()
    step = table.column("timestep").to_numpy()
    xy = np.stack(
        [table.column("position_x").to_numpy(), table.column("position_y").to_numpy()], -1
    )
    heading = table.column("heading").to_numpy()
    for name, values in (("position_x", xy[:, 0]), ("position_y", xy[:, 1]), ("heading", heading)):
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise ScenarioFormatError(
                f"{path} row {bad[0]}: column {name!r} is not a finite number"
            )
    frame = LocalFrame(CITY_NAMES[city_name], np.append(np.round(xy.mean(axis=0), 0), 0.0))
    scenario_id = (
        str(table.column("scenario_id")[0].as_py())
        if "scenario_id" in table.column_names
        else folder.name
    )
    intersection_map = read_map(_map_file(folder), frame, f"av2_{scenario_id}", report)
    start_ns = int(table.column("start_timestamp")[0].as_py())
    grid = start_ns + FRAME_PERIOD_NS * np.arange(int(step.max()) + 1, dtype=np.int64)
    local = frame.to_local(xy)
    reach = _map_reach(intersection_map)
    tracks, obstacles = [], []
    for track_id in dict.fromkeys(ids.tolist()):
        rows = np.flatnonzero(ids == track_id)
        rows = rows[np.argsort(step[rows])]
        kind = kinds[rows[0]]
        agent_class = FORECAST_CLASSES.get(kind)
        if agent_class is None:
            travel = float(np.ptp(local[rows], axis=0).max()) if len(rows) > 1 else 0.0
            if kind in ("static", "riderless_bicycle", "construction") and travel < STATIC_TRAVEL_M:
                middle = rows[len(rows) // 2]
                obstacles.append(
                    StaticObstacle(
                        f"{kind}_{len(obstacles):03d}",
                        kind,
                        np.append(local[middle], 0.5),
                        float(heading[middle]),
                        np.array([1.0, 1.0, 1.0]),
                    )
                )
                report.static[kind] += 1
            else:
                report.drop(kind, "not one of the 8 classes")
            continue
        size = np.tile(TYPICAL_SIZE_M[agent_class], (len(rows), 1))
        track = resample_track(
            str(track_id),
            agent_class,
            grid[step[rows]],
            local[rows],
            0.5 * size[:, 2],
            heading[rows],
            size,
            grid,
            {"source_class": kind, "size_source": "class default (forecasting data has no sizes)"},
        )
        track = None if track is None else _clip_to_map(track, reach)
        if track is None:
            report.drop(kind, "outside the mapped area (more than 2 m from road and crosswalks)")
            continue
        tracks.append(track)
        report.keep(kind, agent_class)
    focal = (
        str(table.column("focal_track_id")[0].as_py())
        if "focal_track_id" in table.column_names
        else None
    )
    start = utc_from_ns(start_ns)
    scenario = Scenario(
        scenario_id=f"av2_{scenario_id}",
        map_id=intersection_map.map_id,
        source=SOURCE,
        t_ns=grid,
        tracks=tuple(tracks),
        signals=(),
        conditions=Conditions(Weather.CLEAR, time_of_day_of(start, intersection_map.origin), start),
        ego_id=focal if focal in {t.track_id for t in tracks if t.valid.all()} else None,
        metadata={
            "source_folder": folder.name,
            "kind": "motion forecasting",
            "weather": "not recorded; clear assumed",
            "signals": "not recorded",
            "sizes": "class defaults",
        },
    )
    return Imported(_with_obstacles(intersection_map, obstacles), scenario, report)
