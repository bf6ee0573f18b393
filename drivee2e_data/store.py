"""Scenario bundles and maps on disk: Parquet for per-frame tables, JSON for everything else.

Layout under a data root (ARCHITECTURE.md):

    maps/<map_id>.json
    scenarios/<scenario_id>/tracks.parquet    one row per track per frame of the track's span
    scenarios/<scenario_id>/signals.parquet   one row per signal per frame
    scenarios/<scenario_id>/meta.json         timeline, conditions, ego, route, curation

Writes are atomic (temporary name in the same folder, then rename) and byte-deterministic.
Reads validate every row and raise `ScenarioFormatError` naming file, row and column.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

from drivee2e_data import mapjson
from drivee2e_data.errors import ScenarioFormatError, SchemaVersionError
from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.scenario import (
    FRAME_PERIOD_NS,
    AgentClass,
    BehaviorLabel,
    Conditions,
    Route,
    Scenario,
    SignalTimeline,
    SubScenario,
    TimeOfDay,
    Track,
    Weather,
)

SCHEMA_VERSION = 1
"""Version of the on-disk layout written here; readers refuse anything newer."""

_FLOAT_COLUMNS = ("x", "y", "z", "yaw", "length", "width", "height", "vx", "vy")
_TRACK_SCHEMA = pa.schema(
    [("track_id", pa.string()), ("class", pa.string()), ("t_ns", pa.int64())]
    + [(name, pa.float64()) for name in _FLOAT_COLUMNS]
    + [("valid", pa.bool_())]
)
_SIGNAL_SCHEMA = pa.schema(
    [("signal_id", pa.string()), ("t_ns", pa.int64()), ("state", pa.uint8())]
)


# ---------------------------------------------------------------- paths and atomic writes


def scenario_dir(root: Path, scenario_id: str) -> Path:
    return Path(root) / "scenarios" / scenario_id


def map_path(root: Path, map_id: str) -> Path:
    return Path(root) / "maps" / f"{map_id}.json"


def scenario_ids(root: Path) -> list[str]:
    """Ids of the finished bundles under `root`, sorted; temporary folders are skipped."""
    folder = Path(root) / "scenarios"
    if not folder.is_dir():
        return []
    return sorted(p.name for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))


def map_ids(root: Path) -> list[str]:
    folder = Path(root) / "maps"
    if not folder.is_dir():
        return []
    return sorted(p.stem for p in folder.glob("*.json") if not p.name.startswith("."))


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write `data` to `path` through a temporary file in the same folder and a rename. The
    file gets the mode an ordinary write would (0666 less the umask), not mkstemp's 0600."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        os.fchmod(handle, 0o666 & ~_umask())
        with os.fdopen(handle, "wb") as stream:
            stream.write(data)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


@contextmanager
def _atomic_folder(final: Path) -> Iterator[Path]:
    """A temporary sibling folder that replaces `final` only if the block finishes."""
    final.parent.mkdir(parents=True, exist_ok=True)
    temporary = Path(tempfile.mkdtemp(prefix=f".{final.name}.", dir=final.parent))
    try:
        temporary.chmod(0o777 & ~_umask())  # as an ordinary mkdir would, not mkdtemp's 0700
        yield temporary
        if final.exists():
            retired = Path(tempfile.mkdtemp(prefix=f".{final.name}.old.", dir=final.parent))
            os.replace(final, retired / final.name)
            os.replace(temporary, final)
            shutil.rmtree(retired)
        else:
            os.replace(temporary, final)
    except BaseException:
        shutil.rmtree(temporary, ignore_errors=True)
        raise


def _json_bytes(document: Any) -> bytes:
    return (json.dumps(document, indent=1, ensure_ascii=False) + "\n").encode("utf-8")


# ---------------------------------------------------------------- maps


def write_map(root: Path, intersection_map: IntersectionMap) -> Path:
    """Write `maps/<map_id>.json` atomically and return its path."""
    path = map_path(root, intersection_map.map_id)
    document = {"schema_version": SCHEMA_VERSION, **mapjson.map_to_dict(intersection_map)}
    write_bytes_atomic(path, _json_bytes(document))
    return path


def read_map(root: Path, map_id: str) -> IntersectionMap:
    """Read and validate `maps/<map_id>.json`."""
    path = map_path(root, map_id)
    document = _read_json(path)
    _check_schema(path, document)
    return mapjson.map_from_dict(document, where=str(path))


# ---------------------------------------------------------------- scenarios


def write_scenario(root: Path, scenario: Scenario) -> Path:
    """Write the bundle `scenarios/<scenario_id>/` atomically (replacing an older one)."""
    final = scenario_dir(root, scenario.scenario_id)
    with _atomic_folder(final) as folder:
        pq.write_table(_tracks_table(scenario), folder / "tracks.parquet", compression="zstd")
        pq.write_table(_signals_table(scenario), folder / "signals.parquet", compression="zstd")
        (folder / "meta.json").write_bytes(_json_bytes(meta_document(scenario)))
    return final


def read_timeline(root: Path, scenario_id: str) -> tuple[int, int]:
    """A bundle's first frame time (ns) and number of frames, from its meta.json alone."""
    meta_file = scenario_dir(root, scenario_id) / "meta.json"
    return meta_timeline(_read_json(meta_file), meta_file)


def read_meta(root: Path, scenario_id: str) -> dict[str, Any]:
    """A bundle's meta.json as a dict (schema version checked), without reading its tables."""
    meta_file = scenario_dir(root, scenario_id) / "meta.json"
    meta = _read_json(meta_file)
    _check_schema(meta_file, meta)
    return meta


def write_metadata_entry(root: Path, scenario_id: str, key: str, value: Any) -> None:
    """Set `metadata[key]` in a bundle's meta.json, atomically, leaving its tables as they are."""
    meta_file = scenario_dir(root, scenario_id) / "meta.json"
    meta = read_meta(root, scenario_id)
    metadata = meta.get("metadata")
    if not isinstance(metadata, dict):
        raise ScenarioFormatError(f"{meta_file}: metadata must be an object")
    metadata[key] = value
    write_bytes_atomic(meta_file, _json_bytes(meta))


def meta_timeline(meta: dict[str, Any], meta_file: Path) -> tuple[int, int]:
    """The first frame time (ns) and number of frames of a bundle's meta.json `meta`, read
    from `meta_file` (validated: named in errors)."""
    _check_schema(meta_file, meta)
    timeline = _get(meta, "timeline", dict, meta_file)
    t0_ns = _get(timeline, "t0_ns", int, meta_file, "timeline.")
    num_frames = _get(timeline, "num_frames", int, meta_file, "timeline.")
    if num_frames < 2:
        raise ScenarioFormatError(
            f"{meta_file}: timeline.num_frames is {num_frames}, expected >= 2"
        )
    period_ns = _get(timeline, "period_ns", int, meta_file, "timeline.")
    if period_ns != FRAME_PERIOD_NS:
        raise ScenarioFormatError(
            f"{meta_file}: timeline.period_ns is {period_ns}, expected {FRAME_PERIOD_NS} (10 Hz)"
        )
    return t0_ns, num_frames


def read_scenario(root: Path, scenario_id: str, *, require_map: bool = True) -> Scenario:
    """Read and validate one bundle; with `require_map`, its map file must exist too."""
    folder = scenario_dir(root, scenario_id)
    if not folder.is_dir():
        raise ScenarioFormatError(f"{folder}: no such scenario bundle")
    meta_file = folder / "meta.json"
    meta = _read_json(meta_file)
    t0_ns, num_frames = meta_timeline(meta, meta_file)
    map_id = _get(meta, "map_id", str, meta_file)
    if require_map and not map_path(root, map_id).is_file():
        raise ScenarioFormatError(
            f"{meta_file}: map_id {map_id!r} names a missing map ({map_path(root, map_id)})"
        )
    track_meta = _get(meta, "tracks", dict, meta_file)
    tracks = _read_tracks(folder / "tracks.parquet", t0_ns, num_frames, track_meta)
    signal_meta = _get(meta, "signals", dict, meta_file)
    signals = _read_signals(folder / "signals.parquet", t0_ns, num_frames, signal_meta)
    try:
        return Scenario(
            scenario_id=_get(meta, "scenario_id", str, meta_file),
            map_id=map_id,
            source=_get(meta, "source", str, meta_file),
            t_ns=t0_ns + FRAME_PERIOD_NS * np.arange(num_frames, dtype=np.int64),
            tracks=tracks,
            signals=signals,
            conditions=_conditions_from(meta, meta_file),
            ego_id=meta.get("ego_id"),
            route=_route_from(meta.get("route"), meta_file),
            behavior=_behavior_from(meta.get("behavior"), meta_file),
            quality=meta.get("quality"),
            metadata=meta.get("metadata", {}),
        )
    except ScenarioFormatError as error:
        raise ScenarioFormatError(f"{folder}: {error}") from None


def meta_document(scenario: Scenario) -> dict[str, Any]:
    route = scenario.route
    behavior = scenario.behavior
    return {
        "schema_version": SCHEMA_VERSION,
        "scenario_id": scenario.scenario_id,
        "map_id": scenario.map_id,
        "source": scenario.source,
        "timeline": {
            "t0_ns": int(scenario.t_ns[0]),
            "num_frames": scenario.num_frames,
            "period_ns": FRAME_PERIOD_NS,
        },
        "ego_id": scenario.ego_id,
        "route": None
        if route is None
        else {"lane_ids": list(route.lane_ids), "waypoints_xy_m": route.waypoints_xy_m.tolist()},
        "conditions": {
            "weather": scenario.conditions.weather.value,
            "time_of_day": scenario.conditions.time_of_day.value,
            "start_time_utc": scenario.conditions.start_time_utc.isoformat(),
        },
        "behavior": None
        if behavior is None
        else {"sub_scenario": behavior.sub_scenario.value, "source": behavior.source},
        "quality": None if scenario.quality is None else dict(scenario.quality),
        "tracks": {
            t.track_id: {"class": t.agent_class.value, "metadata": dict(t.metadata)}
            for t in scenario.tracks
        },
        "signals": {s.signal_id: {"origin": s.origin} for s in scenario.signals},
        "metadata": dict(scenario.metadata),
    }


def _tracks_table(scenario: Scenario) -> pa.Table:
    columns: dict[str, list[Any]] = {name: [] for name in _TRACK_SCHEMA.names}
    for track in scenario.tracks:
        valid_frames = np.flatnonzero(track.valid)
        if valid_frames.size == 0:
            raise ScenarioFormatError(f"track {track.track_id!r}: no valid frame, nothing to store")
        span = slice(int(valid_frames[0]), int(valid_frames[-1]) + 1)
        count = span.stop - span.start
        columns["track_id"].extend([track.track_id] * count)
        columns["class"].extend([track.agent_class.value] * count)
        columns["t_ns"].extend(scenario.t_ns[span].tolist())
        arrays = (
            track.x_m,
            track.y_m,
            track.z_m,
            track.yaw_rad,
            track.length_m,
            track.width_m,
            track.height_m,
            track.vx_mps,
            track.vy_mps,
        )
        for name, values in zip(_FLOAT_COLUMNS, arrays, strict=True):
            columns[name].extend(values[span].tolist())
        columns["valid"].extend(track.valid[span].tolist())
    return pa.table(columns, schema=_TRACK_SCHEMA)


def _signals_table(scenario: Scenario) -> pa.Table:
    frames = scenario.num_frames
    return pa.table(
        {
            "signal_id": [s.signal_id for s in scenario.signals for _ in range(frames)],
            "t_ns": np.tile(scenario.t_ns, len(scenario.signals)),
            "state": np.concatenate(
                [s.states for s in scenario.signals] or [np.zeros(0, np.uint8)]
            ),
        },
        schema=_SIGNAL_SCHEMA,
    )


# numpy's dtype for each fixed-width Arrow type this project writes (bundles, the logs index).
# Columns are converted through their buffers in both directions: pyarrow's own conversions
# (`to_numpy`, `to_pydict`, `pa.array`, `pa.table`) import pandas wherever it is installed,
# 0.4-0.6 s of every collector worker's first world on an H100 host (16 at once).
_NUMPY_TYPES = {pa.int8(): np.int8, pa.int32(): np.int32, pa.int64(): np.int64,
                pa.uint8(): np.uint8, pa.float64(): np.float64}  # fmt: skip


def column_values(column: pa.ChunkedArray) -> NDArray:
    """A fixed-width or boolean column without nulls as a numpy array, read from its buffers."""
    array = column.combine_chunks()
    if array.null_count:  # not in files this project writes: pyarrow's conversion
        return array.to_numpy(zero_copy_only=False)
    data = array.buffers()[1]
    if pa.types.is_boolean(array.type):
        bits = np.unpackbits(np.frombuffer(data, np.uint8), bitorder="little")
        return bits[array.offset : array.offset + len(array)].astype(bool)
    values = np.frombuffer(data, _NUMPY_TYPES[array.type])
    return values[array.offset : array.offset + len(array)].copy()


def arrow_column(values: list, arrow_type: pa.DataType) -> pa.Array:
    """Python values (strings, or numbers of a fixed-width type) as an Arrow array made from its
    buffers."""
    if pa.types.is_string(arrow_type):
        encoded = [str(value).encode() for value in values]
        offsets = np.zeros(len(encoded) + 1, np.int32)
        np.cumsum([len(text) for text in encoded], out=offsets[1:])
        data = pa.py_buffer(b"".join(encoded))
        return pa.Array.from_buffers(arrow_type, len(encoded), [None, pa.py_buffer(offsets), data])
    numbers = np.asarray(values, dtype=_NUMPY_TYPES[arrow_type])
    return pa.Array.from_buffers(arrow_type, len(numbers), [None, pa.py_buffer(numbers)])


def _read_table(path: Path, schema: pa.Schema) -> pa.Table:
    if not path.is_file():
        raise ScenarioFormatError(f"{path}: file is missing")
    try:
        # the file itself, not `pq.read_table`: that goes through pyarrow.dataset, whose import
        # took 0.7 s of each collector worker's first set-up on an H100 host (16 at once)
        with pq.ParquetFile(path) as parquet:
            table = parquet.read()
    except (pa.ArrowException, OSError) as error:
        raise ScenarioFormatError(f"{path}: not a readable Parquet file ({error})") from None
    for expected in schema:
        if expected.name not in table.column_names:
            raise ScenarioFormatError(f"{path}: column {expected.name!r} is missing")
        actual = table.schema.field(expected.name).type
        if actual != expected.type:
            raise ScenarioFormatError(
                f"{path}: column {expected.name!r} has type {actual}, expected {expected.type}"
            )
    return table


def _frame_index(path: Path, t_ns: np.ndarray, t0_ns: int, num_frames: int) -> np.ndarray:
    offset = t_ns - t0_ns
    frame = offset // FRAME_PERIOD_NS
    bad = np.flatnonzero((offset % FRAME_PERIOD_NS != 0) | (frame < 0) | (frame >= num_frames))
    if bad.size:
        raise ScenarioFormatError(
            f"{path} row {bad[0]}: t_ns {t_ns[bad[0]]} is not a frame of the timeline "
            f"(t0 {t0_ns}, {num_frames} frames at 10 Hz)"
        )
    return frame


def _read_tracks(
    path: Path, t0_ns: int, num_frames: int, track_meta: dict[str, Any]
) -> list[Track]:
    table = _read_table(path, _TRACK_SCHEMA)
    track_ids = np.asarray(table.column("track_id").to_pylist(), dtype=object)
    classes = table.column("class").to_pylist()
    t_ns = column_values(table.column("t_ns"))
    valid = column_values(table.column("valid"))
    values = {name: column_values(table.column(name)) for name in _FLOAT_COLUMNS}
    frames = _frame_index(path, t_ns, t0_ns, num_frames)
    known_classes = {c.value for c in AgentClass}
    for name in _FLOAT_COLUMNS:
        bad = np.flatnonzero(valid & ~np.isfinite(values[name]))
        if bad.size:
            row = int(bad[0])
            raise ScenarioFormatError(
                f"{path} row {row}: column {name!r} is {values[name][row]} for track "
                f"{track_ids[row]!r} at t_ns {t_ns[row]}, expected a finite value"
            )
    tracks: list[Track] = []
    order = list(dict.fromkeys(track_ids.tolist()))
    for track_id in order:
        rows = np.flatnonzero(track_ids == track_id)
        track_frames = frames[rows]
        step = np.diff(track_frames)
        if (step <= 0).any():
            row = int(rows[np.flatnonzero(step <= 0)[0] + 1])
            kind = "duplicates an earlier row" if step.min() == 0 else "is out of time order"
            raise ScenarioFormatError(
                f"{path} row {row}: track {track_id!r} at t_ns {t_ns[row]} {kind}"
            )
        track_classes = {classes[r] for r in rows}
        for row in rows:
            if classes[row] not in known_classes:
                raise ScenarioFormatError(
                    f"{path} row {row}: column 'class' is {classes[row]!r} for track {track_id!r}, "
                    f"expected one of {sorted(known_classes)}"
                )
        if len(track_classes) > 1:
            raise ScenarioFormatError(
                f"{path}: track {track_id!r} has several classes {sorted(track_classes)}"
            )
        arrays = {}
        for name in _FLOAT_COLUMNS:
            full = np.full(num_frames, np.nan)
            full[track_frames] = values[name][rows]
            arrays[name] = full
        full_valid = np.zeros(num_frames, bool)
        full_valid[track_frames] = valid[rows]
        entry = track_meta.get(track_id, {})
        try:
            tracks.append(
                Track(
                    track_id=track_id,
                    agent_class=AgentClass(classes[rows[0]]),
                    x_m=arrays["x"],
                    y_m=arrays["y"],
                    z_m=arrays["z"],
                    yaw_rad=arrays["yaw"],
                    length_m=arrays["length"],
                    width_m=arrays["width"],
                    height_m=arrays["height"],
                    vx_mps=arrays["vx"],
                    vy_mps=arrays["vy"],
                    valid=full_valid,
                    metadata=entry.get("metadata", {}),
                )
            )
        except ScenarioFormatError as error:
            raise ScenarioFormatError(f"{path}: {error}") from None
    return tracks


def _read_signals(
    path: Path, t0_ns: int, num_frames: int, signal_meta: dict[str, Any]
) -> list[SignalTimeline]:
    table = _read_table(path, _SIGNAL_SCHEMA)
    signal_ids = np.asarray(table.column("signal_id").to_pylist(), dtype=object)
    frames = _frame_index(path, column_values(table.column("t_ns")), t0_ns, num_frames)
    states = column_values(table.column("state"))
    signals = []
    for signal_id in dict.fromkeys(signal_ids.tolist()):
        rows = np.flatnonzero(signal_ids == signal_id)
        if len(rows) != num_frames or not np.array_equal(frames[rows], np.arange(num_frames)):
            raise ScenarioFormatError(
                f"{path}: signal {signal_id!r} has {len(rows)} rows, expected one per frame "
                f"({num_frames}) in time order"
            )
        origin = signal_meta.get(signal_id, {}).get("origin", "measured")
        try:
            signals.append(SignalTimeline(signal_id, states[rows], origin))
        except ScenarioFormatError as error:
            raise ScenarioFormatError(f"{path}: {error}") from None
    return signals


# ---------------------------------------------------------------- JSON helpers


def _read_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise ScenarioFormatError(f"{path}: file is missing")
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ScenarioFormatError(f"{path}: not valid JSON ({error})") from None
    if not isinstance(document, dict):
        raise ScenarioFormatError(f"{path}: expected a JSON object at the top level")
    return document


def _check_schema(path: Path, document: dict[str, Any]) -> None:
    version = document.get("schema_version")
    if not isinstance(version, int):
        raise ScenarioFormatError(f"{path}: key 'schema_version' missing or not an integer")
    if version > SCHEMA_VERSION:
        raise SchemaVersionError(
            f"{path}: written by schema version {version}, this drivee2e-data reads up to "
            f"{SCHEMA_VERSION}; upgrade drivee2e-data"
        )


def _get(document: dict[str, Any], key: str, kind: type, path: Path, prefix: str = "") -> Any:
    if key not in document:
        raise ScenarioFormatError(f"{path}: key {prefix}{key!r} is missing")
    value = document[key]
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise ScenarioFormatError(
            f"{path}: key {prefix}{key!r} is {value!r}, expected {kind.__name__}"
        )
    return value


def _parse(path: Path, key: str, parse: Callable[[Any], Any], value: Any) -> Any:
    try:
        return parse(value)
    except (ValueError, TypeError, KeyError) as error:
        raise ScenarioFormatError(f"{path}: key {key!r} is {value!r}: {error}") from None


def _conditions_from(meta: dict[str, Any], path: Path) -> Conditions:
    conditions = _get(meta, "conditions", dict, path)
    return Conditions(
        weather=_parse(path, "conditions.weather", Weather, conditions.get("weather")),
        time_of_day=_parse(
            path, "conditions.time_of_day", TimeOfDay, conditions.get("time_of_day")
        ),
        start_time_utc=_parse(
            path,
            "conditions.start_time_utc",
            datetime.fromisoformat,
            conditions.get("start_time_utc"),
        ),
    )


def _route_from(route: Any, path: Path) -> Route | None:
    if route is None:
        return None
    return _parse(
        path, "route", lambda r: Route(tuple(r["lane_ids"]), np.asarray(r["waypoints_xy_m"])), route
    )


def _behavior_from(behavior: Any, path: Path) -> BehaviorLabel | None:
    if behavior is None:
        return None
    return _parse(
        path,
        "behavior",
        lambda b: BehaviorLabel(SubScenario(b["sub_scenario"]), str(b["source"])),
        behavior,
    )
