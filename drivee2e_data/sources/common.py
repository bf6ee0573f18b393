"""What every importer shares: the class report, typical sizes, 10 Hz resampling, clip cutting,
geodesy, and reading tables with errors that name file, row and column.
"""

from __future__ import annotations

import csv
import math
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pyproj import Transformer

from drivee2e_data.errors import ScenarioFormatError
from drivee2e_data.geometry import wrap_angle
from drivee2e_data.hdmap import GeoOrigin, Lane, TurnDirection
from drivee2e_data.scenario import (
    FRAME_PERIOD_NS,
    AgentClass,
    Track,
)

# Typical (length, width, height) in metres, used where a source gives no box size.
TYPICAL_SIZE_M = {
    AgentClass.CAR: (4.6, 1.85, 1.5),
    AgentClass.VAN: (5.2, 2.0, 2.1),
    AgentClass.TRUCK: (8.0, 2.5, 3.4),
    AgentClass.BUS: (11.5, 2.55, 3.2),
    AgentClass.PEDESTRIAN: (0.6, 0.6, 1.72),
    AgentClass.CYCLIST: (1.8, 0.65, 1.7),
    AgentClass.TRICYCLIST: (2.8, 1.2, 1.8),
    AgentClass.MOTORCYCLIST: (2.1, 0.8, 1.6),
}
SUCCESSOR_GAP_M = 1.0  # a lane starting this close to where another ends follows it
MAX_INTERPOLATION_GAP_NS = 300_000_000  # resampling bridges source gaps up to 0.3 s, no more


@dataclass
class ImportReport:
    """What an import kept, mapped onto another class, turned into static obstacles, or dropped."""

    kept: Counter[str] = field(default_factory=Counter)  # source class -> tracks kept as is
    mapped: dict[str, tuple[str, int]] = field(default_factory=dict)  # source -> (our class, n)
    static: Counter[str] = field(default_factory=Counter)  # source class -> static obstacles
    dropped: dict[str, tuple[str, int]] = field(default_factory=dict)  # source -> (reason, n)
    warnings: list[str] = field(default_factory=list)

    def keep(self, source_class: str, agent_class: AgentClass) -> None:
        if source_class.lower() == agent_class.value:
            self.kept[source_class] += 1
        else:
            _, count = self.mapped.get(source_class, (agent_class.value, 0))
            self.mapped[source_class] = (agent_class.value, count + 1)

    def drop(self, source_class: str, reason: str) -> None:
        _, count = self.dropped.get(source_class, (reason, 0))
        self.dropped[source_class] = (reason, count + 1)

    def warn(self, message: str) -> None:
        self.warnings.append(message)

    def lines(self) -> list[str]:
        """One line per source class, for the CLI's summary."""
        rows = [f"  {name}: kept {n}" for name, n in sorted(self.kept.items())]
        rows += [f"  {name}: mapped to {to} ({n})" for name, (to, n) in sorted(self.mapped.items())]
        rows += [f"  {name}: static obstacle ({n})" for name, n in sorted(self.static.items())]
        rows += [
            f"  {name}: dropped ({n}): {why}" for name, (why, n) in sorted(self.dropped.items())
        ]
        return rows


def resample_track(
    track_id: str,
    agent_class: AgentClass,
    t_ns: NDArray[np.int64],
    xy_m: NDArray[np.float64],
    z_m: NDArray[np.float64],
    yaw_rad: NDArray[np.float64],
    size_m: NDArray[np.float64],
    grid_ns: NDArray[np.int64],
    metadata: dict[str, str] | None = None,
) -> Track | None:
    """A track on the 10 Hz grid from samples at jittering times (sorted `t_ns: (N,)`).

    Positions and heading interpolate linearly (heading unwrapped); sizes take the nearest
    sample; velocity is the central difference of the resampled positions. Grid times farther
    than 0.3 s from a sample on either side are invalid. None when no grid time is covered.
    """
    grid = np.asarray(grid_ns, dtype=np.int64)
    t = np.asarray(t_ns, dtype=np.int64)
    right = np.clip(np.searchsorted(t, grid, side="left"), 0, len(t) - 1)
    left = np.clip(right - 1, 0, len(t) - 1)
    exact = t[right] == grid
    left = np.where(exact, right, left)
    inside = (
        (grid >= t[0])
        & (grid <= t[-1])
        & ((t[right] - t[left] <= MAX_INTERPOLATION_GAP_NS) | exact)
    )
    if not inside.any():
        return None
    span = np.maximum(t[right] - t[left], 1)
    weight = np.where(exact, 0.0, (grid - t[left]) / span)
    yaw = np.unwrap(yaw_rad)
    x = xy_m[left, 0] + weight * (xy_m[right, 0] - xy_m[left, 0])
    y = xy_m[left, 1] + weight * (xy_m[right, 1] - xy_m[left, 1])
    z = z_m[left] + weight * (z_m[right] - z_m[left])
    heading = (yaw[left] + weight * (yaw[right] - yaw[left]) + np.pi) % (2 * np.pi) - np.pi
    nearest = np.where(weight < 0.5, left, right)
    size = size_m[nearest]
    vx, vy = _velocity(x, y, inside)
    nan = np.full(len(grid), np.nan)
    return Track(
        track_id=track_id,
        agent_class=agent_class,
        x_m=np.where(inside, x, nan),
        y_m=np.where(inside, y, nan),
        z_m=np.where(inside, z, nan),
        yaw_rad=np.where(inside, heading, nan),
        length_m=np.where(inside, size[:, 0], nan),
        width_m=np.where(inside, size[:, 1], nan),
        height_m=np.where(inside, size[:, 2], nan),
        vx_mps=vx,
        vy_mps=vy,
        valid=inside,
        metadata=metadata or {},
    )


def _velocity(x: NDArray, y: NDArray, valid: NDArray) -> tuple[NDArray, NDArray]:
    """Central differences over valid neighbours at 10 Hz (one-sided at the ends of a run)."""
    dt = FRAME_PERIOD_NS / 1e9
    vx, vy = np.full(len(x), np.nan), np.full(len(x), np.nan)
    for k in np.flatnonzero(valid):
        before = k - 1 if k > 0 and valid[k - 1] else k
        after = k + 1 if k + 1 < len(x) and valid[k + 1] else k
        if after == before:
            vx[k] = vy[k] = 0.0
        else:
            vx[k] = (x[after] - x[before]) / ((after - before) * dt)
            vy[k] = (y[after] - y[before]) / ((after - before) * dt)
    return vx, vy


def heading_from_velocity(velocity: np.ndarray) -> np.ndarray:
    """Heading from velocity, held through near-standstill (below 0.2 m/s)."""
    heading = np.arctan2(velocity[:, 1], velocity[:, 0])
    moving = np.hypot(velocity[:, 0], velocity[:, 1]) > 0.2
    last = heading[np.argmax(moving)] if moving.any() else 0.0
    for k in range(len(heading)):
        if moving[k]:
            last = heading[k]
        heading[k] = last
    return heading


def grid_between(first_ns: int, last_ns: int) -> NDArray[np.int64]:
    """10 Hz times from `first_ns` up to `last_ns`."""
    count = (last_ns - first_ns) // FRAME_PERIOD_NS + 1
    return first_ns + FRAME_PERIOD_NS * np.arange(count, dtype=np.int64)


# ---------------------------------------------------------------- geodesy


def utm_zone_of(longitude_deg: float) -> int:
    return int((longitude_deg + 180.0) // 6) + 1


def utm_transformer(zone: int, northern: bool = True, inverse: bool = False) -> Transformer:
    """WGS84 (lon, lat) to UTM easting/northing, or back with `inverse`."""
    utm = f"EPSG:{(32600 if northern else 32700) + zone}"
    source, target = (utm, "EPSG:4326") if inverse else ("EPSG:4326", utm)
    return Transformer.from_crs(source, target, always_xy=True)


def geo_origin_of_utm(
    easting_m: float, northing_m: float, zone: int, altitude_m: float = 0.0
) -> GeoOrigin:
    longitude, latitude = utm_transformer(zone, inverse=True).transform(easting_m, northing_m)
    return GeoOrigin(float(latitude), float(longitude), altitude_m)


def utc_from_ns(t_ns: int) -> datetime:
    return datetime.fromtimestamp(t_ns / 1e9, tz=timezone.utc)


# ---------------------------------------------------------------- maps


def prune_lane_references(lanes: Sequence[Lane], source: str, report: ImportReport) -> list[Lane]:
    """The lanes without their references to lanes the map lacks (predecessors, successors,
    neighbours): a map cropped to one site names its neighbours' lanes. Every map reader drops
    them the same way, with one warning counting them."""
    known = {lane.lane_id for lane in lanes}
    dropped = 0
    pruned = []
    for lane in lanes:
        predecessors = tuple(i for i in lane.predecessors if i in known)
        successors = tuple(i for i in lane.successors if i in known)
        left = lane.left_neighbor if lane.left_neighbor in known else None
        right = lane.right_neighbor if lane.right_neighbor in known else None
        dropped += len(lane.predecessors) - len(predecessors)
        dropped += len(lane.successors) - len(successors)
        dropped += (lane.left_neighbor is not None and left is None) + (
            lane.right_neighbor is not None and right is None
        )
        pruned.append(
            replace(
                lane,
                predecessors=predecessors,
                successors=successors,
                left_neighbor=left,
                right_neighbor=right,
            )
        )
    if dropped:
        report.warn(f"{source}: {dropped} lane references point outside the map crop; dropped")
    return pruned


def turn_direction_of(centerline: NDArray[np.float64]) -> TurnDirection:
    """Straight, left, right or U-turn from the heading change along a centerline `(N, 2+)`."""
    start = centerline[min(2, len(centerline) - 1)] - centerline[0]
    end = centerline[-1] - centerline[max(len(centerline) - 3, 0)]
    change = float(wrap_angle(np.arctan2(end[1], end[0]) - np.arctan2(start[1], start[0])))
    if abs(change) > np.deg2rad(150):
        return TurnDirection.U_TURN
    if change > np.deg2rad(30):
        return TurnDirection.LEFT
    if change < -np.deg2rad(30):
        return TurnDirection.RIGHT
    return TurnDirection.STRAIGHT


def link_lanes_by_geometry(lanes: Sequence[Lane]) -> list[Lane]:
    """Successors and predecessors from geometry, for maps that give none: a lane that starts
    within 1 m of where another ends, heading within 60 degrees of its end, follows it."""
    starts = np.array([lane.centerline_m[0, :2] for lane in lanes])
    start_heading = np.array(
        [np.arctan2(*(lane.centerline_m[1, :2] - lane.centerline_m[0, :2])[::-1]) for lane in lanes]
    )
    successors: dict[str, list[str]] = {lane.lane_id: [] for lane in lanes}
    predecessors: dict[str, list[str]] = {lane.lane_id: [] for lane in lanes}
    for lane in lanes:
        end = lane.centerline_m[-1, :2]
        heading = np.arctan2(*(lane.centerline_m[-1, :2] - lane.centerline_m[-2, :2])[::-1])
        close = np.linalg.norm(starts - end, axis=1) < SUCCESSOR_GAP_M
        aligned = np.abs(wrap_angle(start_heading - heading)) < np.deg2rad(60)
        for k in np.flatnonzero(close & aligned):
            if lanes[k].lane_id != lane.lane_id:
                successors[lane.lane_id].append(lanes[k].lane_id)
                predecessors[lanes[k].lane_id].append(lane.lane_id)
    return [
        replace(
            lane,
            successors=tuple(successors[lane.lane_id]),
            predecessors=tuple(predecessors[lane.lane_id]),
        )
        for lane in lanes
    ]


# ---------------------------------------------------------------- reading tables


def read_csv_rows(path: Path, required: Iterable[str]) -> tuple[list[str], list[dict[str, str]]]:
    """Header and rows of a CSV file; a missing file, an empty file or a missing column is an
    error naming the file (and the column)."""
    if not path.is_file():
        raise ScenarioFormatError(f"{path}: file is missing")
    try:
        with path.open(newline="", encoding="utf-8-sig") as stream:
            reader = csv.DictReader(stream)
            header = [name.strip() for name in (reader.fieldnames or [])]
            if not header:
                raise ScenarioFormatError(f"{path}: file is empty (no header row)")
            reader.fieldnames = header
            rows = list(reader)
    except UnicodeDecodeError as error:
        raise ScenarioFormatError(
            f"{path}: not UTF-8 text (byte {error.start}); expected a CSV file"
        ) from None
    except csv.Error as error:  # a field past csv's size limit (binary data without newlines)
        raise ScenarioFormatError(f"{path}: not a readable CSV file ({error})") from None
    for index, row in enumerate(rows, start=2):
        if None in row.values() or None in row:  # fewer or more fields than the header names
            fields = len(header) + len(row.get(None) or []) - sum(v is None for v in row.values())
            last = " (the file ends there: truncated?)" if index == len(rows) + 1 else ""
            raise ScenarioFormatError(
                f"{path} row {index}: {fields} fields, expected {len(header)}{last}"
            )
    missing = [name for name in required if name not in header]
    if missing:
        raise ScenarioFormatError(
            f"{path}: column {missing[0]!r} is missing (header: {', '.join(header)})"
        )
    if not rows:
        raise ScenarioFormatError(f"{path}: file has a header but no rows")
    return header, rows


def same_in_every_row(path: Path, rows: list[dict[str, str]], column: str) -> str:
    """The value `column` holds on every row (one scene is one site); a row that differs is an
    error naming it (a file cut inside its last row shows up here)."""
    first = rows[0][column].strip()
    for index, row in enumerate(rows, start=2):
        if row[column].strip() != first:
            raise ScenarioFormatError(
                f"{path} row {index}: column {column!r} is {row[column]!r}, expected {first!r} "
                "as on row 2 (one file holds one site)"
            )
    return first


def number(path: Path, row: int, column: str, text: str | None) -> float:
    """A finite float from a CSV cell; an error naming file, row (1-based, header = 1) and column."""
    try:
        value = float(text) if text is not None else math.nan
    except ValueError:
        raise ScenarioFormatError(
            f"{path} row {row}: column {column!r} is {text!r}, expected a number"
        ) from None
    if not math.isfinite(value):
        raise ScenarioFormatError(
            f"{path} row {row}: column {column!r} is {text!r}, expected a finite number"
        )
    return value
