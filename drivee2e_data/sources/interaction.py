"""INTERACTION dataset (drone view of intersections): track CSVs and Lanelet2 maps.

Vehicle files give heading and box size; pedestrian/bicycle files give neither, so heading
follows velocity and sizes are class defaults (flagged). A 'pedestrian/bicycle' agent faster
than 3 m/s at any time is taken for a cyclist. Maps use the origin (0, 0) (see `lanelet2`).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from drivee2e_data.errors import ScenarioFormatError
from drivee2e_data.scenario import AgentClass, Conditions, Scenario, TimeOfDay, Weather
from drivee2e_data.sources import lanelet2
from drivee2e_data.sources.argoverse2 import Imported
from drivee2e_data.sources.common import (
    TYPICAL_SIZE_M,
    ImportReport,
    grid_between,
    heading_from_velocity,
    number,
    read_csv_rows,
    resample_track,
)
from drivee2e_data.sources.sind import NOMINAL_DATE
from drivee2e_data.sun import start_time_for

SOURCE = "interaction"
CLASSES = {"car": AgentClass.CAR, "truck": AgentClass.TRUCK, "bus": AgentClass.BUS}
WALKING_LIMIT_MPS = 3.0
COLUMNS = ["track_id", "frame_id", "timestamp_ms", "agent_type", "x", "y", "vx", "vy"]


def recordings(source: Path) -> list[tuple[str, list[Path], Path]]:
    """(name, track CSVs, map) per recording under `source`: the release root (`maps/NAME.osm`
    beside `recorded_trackfiles/NAME/*_tracks_NNN.csv`), one recording folder of it, or a flat
    folder holding one map and its CSVs. Files ending `_NNN.csv` form recording `NAME_NNN`."""
    source = Path(source)
    if (source / "recorded_trackfiles").is_dir():
        folders = sorted(p for p in (source / "recorded_trackfiles").iterdir() if p.is_dir())
        maps = source / "maps"
    elif source.parent.name == "recorded_trackfiles":
        folders, maps = [source], source.parent.parent / "maps"
    else:
        osm = sorted(source.glob("*.osm"))
        if len(osm) != 1:
            raise ScenarioFormatError(
                f"{source}: expected the INTERACTION release (maps/ and recorded_trackfiles/), "
                f"one of its recording folders, or a folder with one Lanelet2 map; found "
                f"{len(osm)} *.osm files"
            )
        return _grouped(source, osm[0].stem, osm[0])
    found = []
    for folder in folders:
        osm = maps / f"{folder.name}.osm"
        if not osm.is_file():
            raise ScenarioFormatError(f"{folder}: its map {osm} is missing")
        found += _grouped(folder, folder.name, osm)
    if not found:
        raise ScenarioFormatError(f"{source}: no track CSV in any recording folder")
    return found


def _grouped(folder: Path, name: str, osm: Path) -> list[tuple[str, list[Path], Path]]:
    groups: dict[str, list[Path]] = {}
    for path in sorted(folder.glob("*.csv")):
        match = re.search(r"_(\d+)$", path.stem)
        groups.setdefault(match.group(1) if match else "", []).append(path)
    if not groups:
        raise ScenarioFormatError(f"{folder}: no track CSV")
    return [
        (f"{name}_{number}" if number else name, files, osm)
        for number, files in sorted(groups.items())
    ]


def import_interaction(
    track_csvs: list[Path], osm_map: Path, recording: str | None = None
) -> Imported:
    """Track CSVs of one recording (vehicles and pedestrians) with their Lanelet2 map; the
    scenario is `interaction_<recording>` (default: the map's name)."""
    report = ImportReport()
    map_id = f"interaction_{Path(osm_map).stem}"
    intersection_map = lanelet2.read_map(Path(osm_map), map_id, origin=(0.0, 0.0), report=report)
    entries: dict[str, list[tuple[int, dict[str, str], Path]]] = {}
    for path in map(Path, track_csvs):
        _, rows = read_csv_rows(path, COLUMNS)
        for index, row in enumerate(rows, start=2):
            entries.setdefault(f"{row['agent_type'][:1]}{row['track_id']}", []).append(
                (index, row, path)
            )
    all_ms = [
        number(p, i, "timestamp_ms", r["timestamp_ms"])
        for rows in entries.values()
        for i, r, p in rows
    ]
    t0_ns = int(NOMINAL_DATE.timestamp()) * 1_000_000_000
    first_ms = min(all_ms)
    grid = grid_between(t0_ns, t0_ns + round((max(all_ms) - first_ms) * 1e6))
    tracks = []
    for track_id, rows in entries.items():
        kind = rows[0][1]["agent_type"].strip().lower()
        t_ms = np.array([number(p, i, "timestamp_ms", r["timestamp_ms"]) for i, r, p in rows])
        if np.any(np.diff(t_ms) <= 0):
            index, _, path = rows[int(np.flatnonzero(np.diff(t_ms) <= 0)[0]) + 1]
            raise ScenarioFormatError(
                f"{path} row {index}: column 'timestamp_ms' is out of order for track {track_id!r}"
            )
        xy = np.array([[number(p, i, "x", r["x"]), number(p, i, "y", r["y"])] for i, r, p in rows])
        velocity = np.array(
            [[number(p, i, "vx", r["vx"]), number(p, i, "vy", r["vy"])] for i, r, p in rows]
        )
        if kind in CLASSES:
            agent_class = CLASSES[kind]
            yaw = np.array([number(p, i, "psi_rad", r.get("psi_rad")) for i, r, p in rows])
            size = np.array(
                [
                    [
                        number(p, i, "length", r.get("length")),
                        number(p, i, "width", r.get("width")),
                        TYPICAL_SIZE_M[agent_class][2],
                    ]
                    for i, r, p in rows
                ]
            )
            note = "length and width from the file"
        elif kind in ("pedestrian/bicycle", "pedestrian", "bicycle"):
            fast = np.hypot(velocity[:, 0], velocity[:, 1]).max() > WALKING_LIMIT_MPS
            agent_class = AgentClass.CYCLIST if fast or kind == "bicycle" else AgentClass.PEDESTRIAN
            yaw = heading_from_velocity(velocity)
            size = np.tile(TYPICAL_SIZE_M[agent_class], (len(rows), 1))
            note = "class default (the file has no size)"
        else:
            report.drop(kind, "not one of the 8 classes")
            continue
        t_ns = t0_ns + np.round((t_ms - first_ms) * 1e6).astype(np.int64)
        track = resample_track(
            track_id,
            agent_class,
            t_ns,
            xy,
            0.5 * size[:, 2],
            yaw,
            size,
            grid,
            {"source_class": kind, "size_source": note},
        )
        if track is not None:
            tracks.append(track)
            report.keep(kind, agent_class)
    scenario = Scenario(
        scenario_id=f"interaction_{recording or Path(osm_map).stem}",
        map_id=map_id,
        source=SOURCE,
        t_ns=grid,
        tracks=tuple(tracks),
        signals=(),
        conditions=Conditions(
            Weather.CLEAR,
            TimeOfDay.NOON,
            start_time_for(TimeOfDay.NOON, NOMINAL_DATE.date(), intersection_map.origin),
        ),
        metadata={
            "files": [Path(p).name for p in track_csvs],
            "time and weather": "not recorded; clear, and the sun placed for noon at the map origin",
        },
    )
    return Imported(intersection_map, scenario, report)
