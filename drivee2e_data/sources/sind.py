"""SinD (signalized intersections seen by drone): measured signal-state changes forward-filled
onto a 10 Hz timeline, pedestrian and vehicle tracks where the recording has them, and the
site's Lanelet2 map (UTM zone 31 around lat/lon (0, 0), as the tracks' ground frame).

SinD does not say which map element each signal column belongs to (only a figure does), so the
signal timelines keep the CSV's column names (`traffic_light_1`, `pedestrian_traffic_light_2`)
and are not linked to the map's signal heads.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from drivee2e_data.errors import ScenarioFormatError
from drivee2e_data.hdmap import GeoOrigin, IntersectionMap
from drivee2e_data.scenario import (
    AgentClass,
    Conditions,
    Scenario,
    SignalState,
    SignalTimeline,
    TimeOfDay,
    Track,
    Weather,
)
from drivee2e_data.sources import lanelet2
from drivee2e_data.sources.common import (
    TYPICAL_SIZE_M,
    ImportReport,
    grid_between,
    heading_from_velocity,
    number,
    read_csv_rows,
    resample_track,
)
from drivee2e_data.sources.cutting import cut_clips
from drivee2e_data.sun import start_time_for

SOURCE = "sind"
RAW_FRAME_RATE_HZ = (
    29.97  # video frames; tracks keep every third (Format.md: Frame * 3 = RawFrameID)
)
STATES = {0: SignalState.RED, 1: SignalState.GREEN, 3: SignalState.YELLOW}
VEHICLE_CLASSES = {
    "car": AgentClass.CAR,
    "truck": AgentClass.TRUCK,
    "bus": AgentClass.BUS,
    "motorcycle": AgentClass.MOTORCYCLIST,
    "bicycle": AgentClass.CYCLIST,
    "tricycle": AgentClass.TRICYCLIST,
    "pedestrian": AgentClass.PEDESTRIAN,
}
WEATHERS = {
    "sunny": Weather.CLEAR,
    "clear": Weather.CLEAR,
    "cloudy": Weather.CLOUDY,
    "overcast": Weather.OVERCAST,
    "rainy": Weather.RAIN,
    "rain": Weather.RAIN,
    "foggy": Weather.FOG,
}
NOMINAL_DATE = datetime(2021, 6, 1, tzinfo=timezone.utc)  # SinD gives weekday and hour, no date
CHINA_UTC_OFFSET_H = 8


@dataclass(frozen=True)
class SindImport:
    intersection_map: IntersectionMap
    clips: list[Scenario]
    recording: Scenario  # the whole recording before cutting
    report: ImportReport


def _snake(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", name.strip().lower()).strip("_")


def read_signal_events(
    path: Path, report: ImportReport
) -> tuple[dict[str, list[tuple[float, SignalState]]], float]:
    """Per signal column, (time in ms, state) change events in file order; and the first time.

    A row with an empty timestamp takes its time from RawFrameID; a cell that is not 0, 1 or 3
    becomes UNKNOWN; both with a warning naming the row.
    """
    header, rows = read_csv_rows(path, ["RawFrameID", "timestamp(ms)"])
    columns = [name for name in header if name not in ("RawFrameID", "timestamp(ms)") and name]
    if not columns:
        raise ScenarioFormatError(
            f"{path}: no traffic-light columns after RawFrameID and timestamp(ms)"
        )
    events: dict[str, list[tuple[float, SignalState]]] = {_snake(c): [] for c in columns}
    for index, row in enumerate(rows, start=2):
        raw_frame = number(path, index, "RawFrameID", row["RawFrameID"])
        text = (row["timestamp(ms)"] or "").strip()
        if text:
            time_ms = number(path, index, "timestamp(ms)", text)
        else:
            time_ms = raw_frame / RAW_FRAME_RATE_HZ * 1000.0
            report.warn(
                f"{path.name} row {index}: empty timestamp(ms); taken from RawFrameID {raw_frame:g}"
            )
        for column in columns:
            cell = (row[column] or "").strip()
            try:
                state = STATES[int(float(cell))]
            except (ValueError, KeyError):
                state = SignalState.UNKNOWN
                report.warn(
                    f"{path.name} row {index}: column {column!r} is {cell!r}, expected 0, 1 or 3; unknown"
                )
            events[_snake(column)].append((time_ms, state))
    for name in events:
        events[name].sort(key=lambda event: event[0])
    first = min(times[0][0] for times in events.values())
    return events, first


def forward_fill(events: list[tuple[float, SignalState]], times_ms: np.ndarray) -> np.ndarray:
    """State per time: the last event at or before it (UNKNOWN before the first event)."""
    event_times = np.array([t for t, _ in events])
    states = np.array([s.value for _, s in events], dtype=np.uint8)
    index = np.searchsorted(event_times, times_ms, side="right") - 1
    return np.where(index >= 0, states[np.maximum(index, 0)], SignalState.UNKNOWN.value).astype(
        np.uint8
    )


def _tracks(
    path: Path, columns: list[str], grid_ns: np.ndarray, start_ms: float, report: ImportReport
) -> list[Track]:
    """Tracks of one SinD track CSV; its time `start_ms` is the grid's first frame."""
    _, rows = read_csv_rows(path, columns)
    by_id: dict[str, list[tuple[int, dict[str, str]]]] = {}
    for index, row in enumerate(rows, start=2):
        by_id.setdefault(row["track_id"], []).append((index, row))
    tracks = []
    for track_id, entries in by_id.items():
        kind = entries[0][1]["agent_type"].strip().lower()
        agent_class = VEHICLE_CLASSES.get(kind)
        if agent_class is None:
            report.drop(kind, "not one of the 8 classes")
            report.warn(
                f"{path.name} row {entries[0][0]}: agent_type {kind!r} is not a known SinD class; dropped"
            )
            continue
        t_ms = np.array([number(path, i, "timestamp_ms", r["timestamp_ms"]) for i, r in entries])
        order = np.argsort(t_ms, kind="stable")
        if np.any(np.diff(t_ms[order]) == 0):
            row = entries[int(order[np.flatnonzero(np.diff(t_ms[order]) == 0)[0] + 1])][0]
            raise ScenarioFormatError(
                f"{path} row {row}: track {track_id!r} repeats a timestamp_ms"
            )
        xy = np.array(
            [[number(path, i, "x", r["x"]), number(path, i, "y", r["y"])] for i, r in entries]
        )[order]
        if "yaw_rad" in columns:
            yaw = np.array([number(path, i, "yaw_rad", r["yaw_rad"]) for i, r in entries])[order]
            size = np.array(
                [
                    [
                        number(path, i, "length", r["length"]),
                        number(path, i, "width", r["width"]),
                        TYPICAL_SIZE_M[agent_class][2],
                    ]
                    for i, r in entries
                ]
            )[order]
        else:
            velocity = np.array(
                [
                    [number(path, i, "vx", r["vx"]), number(path, i, "vy", r["vy"])]
                    for i, r in entries
                ]
            )[order]
            yaw = heading_from_velocity(velocity)
            size = np.tile(TYPICAL_SIZE_M[agent_class], (len(entries), 1))
        t_ns = np.round((t_ms[order] - start_ms) * 1e6).astype(np.int64) + int(grid_ns[0])
        track = resample_track(
            track_id,
            agent_class,
            t_ns,
            xy,
            0.5 * size[:, 2],
            yaw,
            size,
            grid_ns,
            {"source_class": kind},
        )
        if track is not None:
            tracks.append(track)
            report.keep(kind, agent_class)
    return tracks


def _conditions(folder: Path, origin: GeoOrigin) -> tuple[Conditions, str]:
    """Weather and the labelled hour from `recording_metas.csv`; the map's origin is nominal, so
    the start is set for the sun to match that hour's label there (`sun.start_time_for`)."""
    metas = folder / "recording_metas.csv"
    weather, hour, note = Weather.CLEAR, 12.0, "no recording_metas.csv; clear and noon assumed"
    if metas.is_file():
        _, rows = read_csv_rows(metas, ["Weather", "Record time period"])
        weather = WEATHERS.get(rows[0]["Weather"].strip().lower(), Weather.CLEAR)
        match = re.match(r"\s*(\d+):(\d+)", rows[0]["Record time period"])
        hour = int(match.group(1)) + int(match.group(2)) / 60 if match else 12.0
        note = "weather and hour from recording_metas.csv; date not given (nominal)"
    time_of_day = TimeOfDay.from_local_hour(hour)
    return Conditions(
        weather, time_of_day, start_time_for(time_of_day, NOMINAL_DATE.date(), origin)
    ), note


def import_sind(city_folder: Path, clip_s: float = 20.0) -> SindImport:
    """A SinD city folder: its `*.osm` map and its one recording folder."""
    city_folder = Path(city_folder)
    report = ImportReport()
    maps = sorted(city_folder.glob("*.osm"))
    recordings = sorted(p for p in city_folder.iterdir() if p.is_dir())
    if not maps:
        raise ScenarioFormatError(f"{city_folder}: no Lanelet2 map (*.osm)")
    if not recordings:
        raise ScenarioFormatError(f"{city_folder}: no recording folder")
    city = _snake(city_folder.name)
    recording = recordings[0]
    intersection_map = lanelet2.read_map(maps[0], f"sind_{city}", origin=(0.0, 0.0), report=report)
    lights = sorted([*recording.glob("Traffic*Light*.csv"), *recording.glob("TrafficLight*.csv")])
    if not lights:
        raise ScenarioFormatError(f"{recording}: no traffic-light CSV")
    events, first_ms = read_signal_events(lights[0], report)
    conditions, note = _conditions(recording, intersection_map.origin)
    t0_ns = int(conditions.start_time_utc.timestamp()) * 1_000_000_000
    track_files = {
        "Ped_smoothed_tracks.csv": ["track_id", "timestamp_ms", "agent_type", "x", "y", "vx", "vy"],
        "Veh_smoothed_tracks.csv": [
            "track_id",
            "timestamp_ms",
            "agent_type",
            "x",
            "y",
            "yaw_rad",
            "length",
            "width",
        ],
    }
    last_ms = max(times[-1][0] for times in events.values())
    present = [
        (recording / name, columns)
        for name, columns in track_files.items()
        if (recording / name).is_file()
    ]
    for path, _ in present:
        _, rows = read_csv_rows(path, ["timestamp_ms"])
        last_ms = max(
            last_ms,
            max(number(path, i, "timestamp_ms", r["timestamp_ms"]) for i, r in enumerate(rows, 2)),
        )
    start_ms = max(0.0, first_ms)
    grid = grid_between(t0_ns, t0_ns + round((last_ms - start_ms) * 1e6))
    tracks = []
    for path, columns in present:
        tracks.extend(_tracks(path, columns, grid, start_ms, report))
    times_ms = start_ms + (grid - grid[0]) / 1e6
    signals = tuple(
        SignalTimeline(name, forward_fill(signal_events, times_ms), origin="measured")
        for name, signal_events in events.items()
    )
    if not present:
        report.warn(f"{recording.name}: no track CSV in the shared sample; signals and map only")
    whole = Scenario(
        scenario_id=f"sind_{city}_{_snake(recording.name)}",
        map_id=intersection_map.map_id,
        source=SOURCE,
        t_ns=grid,
        tracks=tuple(tracks),
        signals=signals,
        conditions=conditions,
        metadata={
            "recording": recording.name,
            "conditions": note,
            "signals_file": lights[0].name,
            "signals_time_origin_ms": start_ms,
        },
    )
    return SindImport(intersection_map, cut_clips(whole, clip_s), whole, report)
