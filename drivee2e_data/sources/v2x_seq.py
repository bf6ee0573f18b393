"""V2X-Seq-TFD (infrastructure view at Beijing intersections): trajectory CSVs, traffic-light
CSVs and `hdmap{id}.json` maps; the native input of the DriveE2E pipeline.

Values in the published maps may be strings ('True', "['(417710.42, 4731538.70)', ...]"); they
are parsed with `ast.literal_eval`, never `eval`. Positions are metres in a shifted UTM zone 50
frame; the local frame subtracts a round offset, and the WGS84 origin is approximate (the shift
is not published), which the map's metadata says.
"""

from __future__ import annotations

import ast
import json
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray

from drivee2e_data.errors import MapFormatError, ScenarioFormatError
from drivee2e_data.geometry import offset_polyline
from drivee2e_data.hdmap import (
    Crosswalk,
    IntersectionMap,
    Lane,
    SignalHead,
    StopLine,
    TurnDirection,
)
from drivee2e_data.scenario import (
    FRAME_PERIOD_NS,
    AgentClass,
    Conditions,
    Scenario,
    SignalState,
    SignalTimeline,
    Track,
    Weather,
)
from drivee2e_data.sources.common import (
    ImportReport,
    geo_origin_of_utm,
    grid_between,
    number,
    prune_lane_references,
    read_csv_rows,
    resample_track,
    same_in_every_row,
    utc_from_ns,
)
from drivee2e_data.sources.markings import derive_markings
from drivee2e_data.sun import time_of_day_of

SOURCE = "v2x_seq"
UTM_ZONE = 50
SUB_TYPES = {
    "car": AgentClass.CAR,
    "van": AgentClass.VAN,
    "truck": AgentClass.TRUCK,
    "bus": AgentClass.BUS,
    "pedestrian": AgentClass.PEDESTRIAN,
    "cyclist": AgentClass.CYCLIST,
    "tricyclist": AgentClass.TRICYCLIST,
    "motorcyclist": AgentClass.MOTORCYCLIST,
}
TRAJECTORY_COLUMNS = [
    "timestamp",
    "id",
    "sub_type",
    "x",
    "y",
    "z",
    "length",
    "width",
    "height",
    "theta",
    "intersect_id",
]
LIGHT_COLUMNS = ["timestamp", "x", "y", "direction", "lane_id", "color_1", "intersect_id"]
COLOURS = {
    "red": SignalState.RED,
    "r": SignalState.RED,
    "yellow": SignalState.YELLOW,
    "y": SignalState.YELLOW,
    "green": SignalState.GREEN,
    "g": SignalState.GREEN,
}
TURNS = {
    "straight": TurnDirection.STRAIGHT,
    "left": TurnDirection.LEFT,
    "right": TurnDirection.RIGHT,
    "uturn": TurnDirection.U_TURN,
    "u_turn": TurnDirection.U_TURN,
    "none": TurnDirection.NONE,
}
LANE_HALF_WIDTH_M = 1.75  # used where a map lane has no boundaries


@dataclass(frozen=True)
class V2XImport:
    intersection_map: IntersectionMap
    scenario: Scenario
    report: ImportReport


def map_id_of(intersect_id: str) -> str:
    return "v2x_" + re.sub(r"[^A-Za-z0-9]+", "_", intersect_id).strip("_")


# ------------------------------------------------------------------ values of the published maps


def _literal(value: Any, where: str) -> Any:
    if not isinstance(value, str):
        return value
    text = value.strip()
    if text in ("True", "False"):
        return text == "True"
    if text in ("None", "", "null"):
        return None
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def _points(value: Any, where: str) -> NDArray[np.float64]:
    """Points from a list of pairs, of '(x, y)' strings, or a string holding such a list."""
    value = _literal(value, where)
    if not isinstance(value, (list, tuple)) or len(value) < 2:
        raise MapFormatError(
            f"{where}: expected a list of at least 2 points, got {str(value)[:60]!r}"
        )
    points = []
    for k, item in enumerate(value):
        item = _literal(item, where)
        try:
            points.append(
                [float(item[0]), float(item[1]), float(item[2]) if len(item) > 2 else 0.0]
            )
        except (TypeError, ValueError, IndexError):
            raise MapFormatError(f"{where}[{k}]: {item!r} is not an (x, y) point") from None
    return np.asarray(points)


def _ids(value: Any, where: str) -> list[str]:
    value = _literal(value, where)
    if value is None:
        return []
    if not isinstance(value, (list, tuple)):
        value = [value]
    return [str(v) for v in value if v is not None and str(v) != "None"]


def read_hdmap(
    path: Path,
    map_id: str,
    offset_m: NDArray[np.float64] | None = None,
    report: ImportReport | None = None,
) -> IntersectionMap:
    """A V2X-Seq `hdmap*.json`; coordinates minus `offset_m` (default: rounded lane mean).
    References to lanes outside the file (a crop) are dropped and counted in `report`."""
    path = Path(path)
    if not path.is_file():
        raise MapFormatError(f"{path}: file is missing")
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise MapFormatError(f"{path}: not valid JSON ({error})") from None
    if "LANE" not in document or not isinstance(document["LANE"], dict):
        raise MapFormatError(f"{path}: key 'LANE' is missing or not an object")
    raw_lanes = {str(k): v for k, v in document["LANE"].items()}
    centres = {
        k: _points(v.get("centerline"), f"{path} LANE[{k}].centerline")
        for k, v in raw_lanes.items()
    }
    if offset_m is None:
        offset_m = np.round(np.concatenate(list(centres.values())).mean(axis=0) / 10.0) * 10.0
        offset_m[2] = 0.0
    lanes = []
    for lane_id, entry in raw_lanes.items():
        where = f"{path} LANE[{lane_id}]"
        centre = centres[lane_id] - offset_m
        if "left_boundary" in entry and "right_boundary" in entry:
            left = _points(entry["left_boundary"], f"{where}.left_boundary") - offset_m
            right = _points(entry["right_boundary"], f"{where}.right_boundary") - offset_m
        else:
            left = np.column_stack([offset_polyline(centre, LANE_HALF_WIDTH_M), centre[:, 2]])
            right = np.column_stack([offset_polyline(centre, -LANE_HALF_WIDTH_M), centre[:, 2]])
        turn_text = (
            str(_literal(entry.get("turn_direction", "none"), where) or "none")
            .lower()
            .replace("-", "_")
        )
        is_intersection = bool(_literal(entry.get("is_intersection", False), where))
        lanes.append(
            Lane(
                lane_id=lane_id,
                centerline_m=centre,
                left_boundary_m=left,
                right_boundary_m=right,
                turn_direction=TURNS.get(turn_text, TurnDirection.NONE)
                if is_intersection
                else TurnDirection.NONE,
                is_intersection=is_intersection,
                predecessors=tuple(_ids(entry.get("predecessors"), f"{where}.predecessors")),
                successors=tuple(_ids(entry.get("successors"), f"{where}.successors")),
                left_neighbor=(_ids(entry.get("l_neighbor_id"), where) or [None])[0],
                right_neighbor=(_ids(entry.get("r_neighbor_id"), where) or [None])[0],
            )
        )
    lanes = prune_lane_references(
        lanes, path.name, report if report is not None else ImportReport()
    )
    stop_lines = []
    for stop_id, entry in (document.get("STOPLINE") or {}).items():
        line = _points(entry.get("centerline"), f"{path} STOPLINE[{stop_id}].centerline") - offset_m
        reach = [
            lane.lane_id
            for lane in lanes
            if not lane.is_intersection
            and shapely.LineString(line[:, :2]).distance(shapely.Point(lane.centerline_m[-1, :2]))
            < 3.0
        ]
        stop_lines.append(StopLine(f"stop_{stop_id}", line, tuple(reach)))
    crosswalks = [
        Crosswalk(
            f"crosswalk_{cid}",
            (_points(entry.get("polygon"), f"{path} CROSSWALK[{cid}].polygon") - offset_m)[:, :2],
        )
        for cid, entry in (document.get("CROSSWALK") or {}).items()
    ]
    controlled = [
        lane_id
        for lane_id, entry in raw_lanes.items()
        if _literal(entry.get("has_traffic_control", False), f"{path} LANE[{lane_id}]") is True
    ]
    try:
        return derive_markings(
            IntersectionMap(
                map_id=map_id,
                origin=geo_origin_of_utm(float(offset_m[0]), float(offset_m[1]), UTM_ZONE),
                lanes=tuple(lanes),
                crosswalks=tuple(crosswalks),
                stop_lines=tuple(stop_lines),
                metadata={
                    "source": SOURCE,
                    "file": path.name,
                    "offset_m": offset_m.tolist(),
                    "origin": "approximate: the published frame is a shifted UTM zone 50",
                },
            ),
            controlled,
        )
    except MapFormatError as error:
        raise MapFormatError(f"{path}: {error}") from None


# ------------------------------------------------------------------ trajectories


def read_trajectories(
    path: Path, offset_m: NDArray[np.float64], report: ImportReport, extra: tuple[str, ...] = ()
) -> tuple[NDArray[np.int64], list[Track], dict[str, str]]:
    """10 Hz grid, tracks and the first row's `extra` columns of a V2X-Seq trajectory CSV.

    Unknown sub_types are dropped with a warning and counted; anything else malformed is an
    error naming file, row and column.
    """
    _, rows = read_csv_rows(path, TRAJECTORY_COLUMNS + list(extra))
    if "intersect_id" in rows[0]:
        same_in_every_row(path, rows, "intersect_id")
    parsed: dict[str, list[tuple[int, float, list[float], str, dict[str, str]]]] = {}
    for index, row in enumerate(rows, start=2):
        sub_type = row["sub_type"].strip().lower()
        if sub_type not in SUB_TYPES:
            report.drop(row["sub_type"].strip() or "(empty)", "not one of the 8 V2X-Seq sub_types")
            report.warn(
                f"{path.name} row {index}: sub_type {row['sub_type']!r} is unknown; row dropped"
            )
            continue
        values = [
            number(path, index, c, row[c])
            for c in ("x", "y", "z", "length", "width", "height", "theta")
        ]
        time_s = number(path, index, "timestamp", row["timestamp"])
        parsed.setdefault(row["id"].strip(), []).append((index, time_s, values, sub_type, row))
    if not parsed:
        raise ScenarioFormatError(f"{path}: no rows with a known sub_type")
    all_times = [entry[1] for entries in parsed.values() for entry in entries]
    grid = grid_between(
        round(min(all_times) * 10) * FRAME_PERIOD_NS, round(max(all_times) * 10) * FRAME_PERIOD_NS
    )
    tracks = []
    for track_id, entries in parsed.items():
        times = np.array([e[1] for e in entries])
        steps = np.diff(times)
        if (steps <= 0).any():
            bad = entries[int(np.flatnonzero(steps <= 0)[0]) + 1][0]
            raise ScenarioFormatError(
                f"{path} row {bad}: column 'timestamp' is out of order for track {track_id!r} "
                "(expected increasing times per track)"
            )
        values = np.array([e[2] for e in entries])
        classes = {e[3] for e in entries}
        if len(classes) > 1:
            raise ScenarioFormatError(
                f"{path} row {entries[0][0]}: track {track_id!r} changes sub_type {sorted(classes)}"
            )
        agent_class = SUB_TYPES[entries[0][3]]
        metadata = {"source_class": entries[0][4]["sub_type"].strip()}
        for column in extra:
            metadata[column] = entries[0][4][column].strip()
        xyz = values[:, :3] - offset_m
        track = resample_track(
            track_id,
            agent_class,
            np.round(times * 1e9).astype(np.int64),
            xyz[:, :2],
            xyz[:, 2],
            values[:, 6],
            values[:, 3:6],
            grid,
            metadata,
        )
        if track is not None:
            tracks.append(track)
            report.keep(entries[0][4]["sub_type"].strip(), agent_class)
    return grid, tracks, {c: rows[0][c] for c in extra}


def read_traffic_lights(
    path: Path,
    grid: NDArray[np.int64],
    offset_m: NDArray[np.float64],
    intersection_map: IntersectionMap,
) -> tuple[list[SignalTimeline], IntersectionMap]:
    """Signal timelines (one per light row key and colour slot) and the map with their heads."""
    header, rows = read_csv_rows(path, LIGHT_COLUMNS)
    site = same_in_every_row(path, rows, "intersect_id")
    if map_id_of(site) != intersection_map.map_id:
        raise ScenarioFormatError(
            f"{path} row 2: column 'intersect_id' is {site!r}, which is not the trajectories' "
            f"site (map {intersection_map.map_id})"
        )
    slots = [k for k in (1, 2, 3) if f"color_{k}" in header]
    events: dict[str, list[tuple[float, SignalState]]] = {}
    heads: dict[str, tuple[NDArray, float, str]] = {}
    lane_ids = {lane.lane_id for lane in intersection_map.lanes}
    for index, row in enumerate(rows, start=2):
        time_s = number(path, index, "timestamp", row["timestamp"])
        lane_id = row["lane_id"].strip()
        if lane_id not in lane_ids:
            raise ScenarioFormatError(
                f"{path} row {index}: column 'lane_id' is {lane_id!r}, a lane the map lacks"
            )
        position = (
            np.array([number(path, index, "x", row["x"]), number(path, index, "y", row["y"])])
            - offset_m[:2]
        )
        direction = row["direction"].strip()
        for k in slots:
            text = (row[f"color_{k}"] or "").strip().lower()
            if not text:
                continue
            if text not in COLOURS:
                raise ScenarioFormatError(
                    f"{path} row {index}: column 'color_{k}' is {row[f'color_{k}']!r}, expected RED, YELLOW or GREEN"
                )
            signal_id = f"light_{lane_id}_{k}"
            events.setdefault(signal_id, []).append((time_s, COLOURS[text]))
            heads[signal_id] = (position, _facing(direction), lane_id)
    timelines = []
    times_s = grid / 1e9
    for signal_id, signal_events in events.items():
        signal_events.sort(key=lambda e: e[0])
        event_times = np.array([t for t, _ in signal_events])
        states = np.array([s.value for _, s in signal_events], np.uint8)
        index = np.searchsorted(event_times, times_s + 1e-6, side="right") - 1
        timelines.append(
            SignalTimeline(
                signal_id, np.where(index >= 0, states[np.maximum(index, 0)], 0).astype(np.uint8)
            )
        )
    signal_heads = tuple(
        SignalHead(
            f"head_{signal_id}",
            signal_id,
            np.append(position, 5.0),
            facing,
            controlled_lane_ids=(lane_id,),
        )
        for signal_id, (position, facing, lane_id) in heads.items()
    )
    first_slot = {
        lane: f"light_{lane}_1" for _, _, lane in heads.values() if f"light_{lane}_1" in heads
    }
    lanes = tuple(
        replace(lane, signal_id=first_slot[lane.lane_id]) if lane.lane_id in first_slot else lane
        for lane in intersection_map.lanes
    )
    return timelines, replace(intersection_map, lanes=lanes, signal_heads=signal_heads)


def _facing(direction: str) -> float:
    """Heading a light faces from a compass word or degrees (east = 0, counter-clockwise)."""
    compass = {
        "east": 0.0,
        "e": 0.0,
        "north": 90.0,
        "n": 90.0,
        "west": 180.0,
        "w": 180.0,
        "south": 270.0,
        "s": 270.0,
    }
    try:
        degrees = compass.get(direction.lower(), float(direction))
    except ValueError:
        degrees = 0.0
    return float(np.deg2rad(degrees))


def import_v2x_seq(trajectories: Path, lights: Path | None, hdmap: Path) -> V2XImport:
    """One V2X-Seq scene: its trajectory CSV, its traffic-light CSV (optional) and its map."""
    report = ImportReport()
    trajectories = Path(trajectories)
    _, first = read_csv_rows(trajectories, ["intersect_id"])
    map_id = map_id_of(first[0]["intersect_id"])
    intersection_map = read_hdmap(hdmap, map_id, report=report)
    offset = np.asarray(intersection_map.metadata["offset_m"])
    grid, tracks, _ = read_trajectories(trajectories, offset, report)
    signals: list[SignalTimeline] = []
    if lights is not None:
        signals, intersection_map = read_traffic_lights(
            Path(lights), grid, offset, intersection_map
        )
    start = utc_from_ns(int(grid[0]))
    scenario = Scenario(
        scenario_id=f"v2x_{trajectories.stem}",
        map_id=map_id,
        source=SOURCE,
        t_ns=grid,
        tracks=tuple(tracks),
        signals=tuple(signals),
        conditions=Conditions(Weather.CLEAR, time_of_day_of(start, intersection_map.origin), start),
        metadata={"trajectories": trajectories.name, "weather": "not recorded; clear assumed"},
    )
    return V2XImport(intersection_map, scenario, report)
