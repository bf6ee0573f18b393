"""Damaged files for every importer: each source laid out in a folder, one of its files replaced
by binary data, by text that is not UTF-8, or cut in half. Used by tests/test_bad_input.py and
scripts/dev/bad_input_catalogue.py (the table in docs/importers.md)."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from tests.conftest import REALDATA
from tests.test_import_v2x import (
    light_rows,
    trajectory_rows,
    write_csv,
    write_hdmap,
    write_interaction_map,
    write_interaction_tracks,
)

BINARY = bytes(range(256)) * 64  # every byte value: no text format reads this
DAMAGES = ("binary", "not UTF-8", "truncated")


def _v2x(folder: Path) -> Path:
    write_csv(folder / "trajectories" / "scene_001.csv", trajectory_rows())
    write_csv(folder / "traffic_light" / "scene_001.csv", light_rows())
    (folder / "maps").mkdir()
    write_hdmap(folder / "maps" / "hdmap4.json")
    return folder


def _drivee2e(folder: Path) -> Path:
    folder.mkdir(parents=True)
    write_csv(folder / "STR_000.csv", trajectory_rows(extra=True))
    write_hdmap(folder / "hdmap4.json")
    (folder / "route.xml").write_text(
        '<routes><route id="0" scenario_csv_id="STR_000" ego_id="101"/></routes>'
    )
    return folder


def _interaction(folder: Path) -> Path:
    write_interaction_map(folder / "maps" / "DR_TEST.osm")
    write_interaction_tracks(folder / "recorded_trackfiles" / "DR_TEST")
    return folder


def _copy(*parts: str) -> Callable[[Path], Path]:
    def make(folder: Path) -> Path:
        source = REALDATA.joinpath(*parts)
        if source.is_dir():
            shutil.copytree(source, folder)
            return folder
        folder.mkdir(parents=True)
        shutil.copy(source, folder / source.name)
        return folder / source.name

    return make


@dataclass(frozen=True)
class Case:
    """One importer, how its source is laid out, and which of its files get damaged."""

    kind: str
    make: Callable[[Path], Path]  # lays the source out under a folder, returns what to import
    files: tuple[str, ...]  # glob patterns under that folder
    needs_realdata: bool = False
    text: bool = True  # whether "not UTF-8" applies to these files


CASES = {
    "drivee2e": Case("drivee2e", _drivee2e, ("STR_000.csv", "route.xml", "hdmap4.json")),
    "v2x-seq": Case(
        "v2x-seq",
        _v2x,
        ("trajectories/scene_001.csv", "traffic_light/scene_001.csv", "maps/hdmap4.json"),
    ),
    "interaction": Case(
        "interaction",
        _interaction,
        ("recorded_trackfiles/DR_TEST/vehicle_tracks_000.csv", "maps/DR_TEST.osm"),
    ),
    "av2": Case(
        "av2",
        _copy("argoverse2", "sensor-log-7fab2350"),
        ("annotations.feather", "city_SE3_egovehicle.feather", "map/log_map_archive_*.json"),
        needs_realdata=True,
    ),
    "av2 forecasting": Case(
        "av2",
        _copy("argoverse2", "forecasting-0a1e6f0a"),
        ("scenario_*.parquet",),
        needs_realdata=True,
        text=False,
    ),
    "commonroad": Case(
        "commonroad",
        _copy("commonroad", "USA_Peach-4_8_T-1.xml"),
        ("USA_Peach-4_8_T-1.xml",),
        needs_realdata=True,
    ),
    "sind": Case(
        "sind",
        _copy("sind", "Data", "Xian"),
        ("Xian_412_m1/Traffic_Lights.csv", "Xian_412_m1/Ped_smoothed_tracks.csv", "*.osm"),
        needs_realdata=True,
    ),
    "lanelet2": Case(
        "lanelet2",
        _copy("lanelet2", "mapping_example.osm"),
        ("mapping_example.osm",),
        needs_realdata=True,
    ),
    "scenarionet": Case(
        "scenarionet",
        _copy("scenarionet", "sd_nuscenes_v1.0-mini_scene-1100.pkl"),
        ("sd_nuscenes_v1.0-mini_scene-1100.pkl",),
        needs_realdata=True,
        text=False,
    ),
}


def damage(path: Path, how: str) -> None:
    """Replace `path` by binary data, by its text in Latin-1 with an accent, or by its first half."""
    data = path.read_bytes()
    if how == "binary":
        path.write_bytes(BINARY)
    elif how == "not UTF-8":
        path.write_bytes("é".encode("latin-1") + data)
    elif how == "truncated":
        path.write_bytes(data[: len(data) // 2])
    else:
        raise ValueError(how)


def prepared(case: Case, pattern: str, how: str, folder: Path) -> tuple[Path, Path]:
    """The case's source laid out under `folder` with `pattern`'s file damaged `how`:
    (what to import, the damaged file)."""
    source = case.make(folder)
    target = next(iter(sorted(folder.glob(pattern))))
    damage(target, how)
    return source, target


def all_cases() -> list[tuple[str, str, str]]:
    """(case name, file pattern, damage) for every combination that applies."""
    return [
        (name, pattern, how)
        for name, case in CASES.items()
        for pattern in case.files
        for how in DAMAGES
        if case.text or how != "not UTF-8"
    ]
