"""Track quality: repair what can be repaired, score what remains, drop what scores too low.

Repairs, in this order, each recorded as an action on the clip:
1. teleports: frames whose jump from both neighbours implies an impossible speed are removed;
2. gaps: invalid runs of at most `MAX_REPAIR_GAP_FRAMES` inside a track are interpolated;
3. reversed heading: a vehicle's yaw pointing against its motion for 0.5 s or more at over
   2.5 m/s (faster than anyone reverses) is flipped;
4. jitter: a track whose positions shake more than `JITTER_LIMIT_M` is smoothed (centred mean).
The score (0..1) multiplies completeness, kinematic plausibility and rule compliance (driving
against the lane direction, leaving the drivable area); tracks under `MIN_SCORE` are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely
from numpy.typing import NDArray

from drivee2e_data.geometry import wrap_angle
from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.scenario import TRACK_ARRAYS, AgentClass, Scenario, Track

FRAME_S = 0.1
MAX_REPAIR_GAP_FRAMES = 10  # gaps up to 1 s are bridged by interpolation
MIN_SCORE = 0.5  # tracks scoring under this are dropped
MIN_FRAMES = 5  # a track seen for less than 0.5 s carries too little to keep
JITTER_LIMIT_M = 0.1  # RMS shake (m) about the 5-frame mean above which a track is smoothed
REVERSED_HEADING_RAD = np.deg2rad(150)  # yaw this far from the direction of motion is reversed
MOVING_MPS = 1.0  # heading checks apply above this speed
FLIP_MPS = 2.5  # a yaw against the motion is an error only this fast (vehicles reverse slowly)
FLIP_MIN_FRAMES = 5  # ...and only when it lasts this long (0.5 s), not a noisy frame or two
AGAINST_LANE_RAD = np.deg2rad(135)  # a vehicle heading this far from its lane drives against it
LANE_MATCH_M = 1.5  # a vehicle this close to a lane centre line is on that lane
OFF_ROAD_M = 2.0  # a vehicle farther than this outside the drivable area is off the road
# Speeds (m/s) beyond which a one-frame jump is a teleport, and plausible limits per class.
MAX_SPEED_MPS = {
    AgentClass.CAR: 45.0,
    AgentClass.VAN: 45.0,
    AgentClass.TRUCK: 40.0,
    AgentClass.BUS: 35.0,
    AgentClass.PEDESTRIAN: 7.0,
    AgentClass.CYCLIST: 15.0,
    AgentClass.TRICYCLIST: 12.0,
    AgentClass.MOTORCYCLIST: 40.0,
}
MAX_ACCEL_MPS2 = 10.0


@dataclass
class TrackQuality:
    track_id: str
    score: float
    completeness: float
    plausibility: float
    compliance: float
    actions: list[str] = field(default_factory=list)
    dropped: bool = False


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """(start, stop) of each run of True."""
    padded = np.concatenate([[False], mask, [False]])
    edges = np.flatnonzero(np.diff(padded.astype(int)))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def _arrays(track: Track) -> dict[str, NDArray]:
    return {name: np.array(getattr(track, name)) for name in TRACK_ARRAYS}


def _remove_teleports(track: Track, arrays: dict, valid: NDArray, actions: list[str]) -> None:
    limit = MAX_SPEED_MPS[track.agent_class] * FRAME_S
    removed = 0
    for k in range(1, len(valid) - 1):
        if not (valid[k - 1] and valid[k] and valid[k + 1]):
            continue
        here = np.array([arrays["x_m"][k], arrays["y_m"][k]])
        before = np.array([arrays["x_m"][k - 1], arrays["y_m"][k - 1]])
        after = np.array([arrays["x_m"][k + 1], arrays["y_m"][k + 1]])
        if np.linalg.norm(here - before) > limit and np.linalg.norm(here - after) > limit:
            valid[k] = False
            removed += 1
    if removed:
        actions.append(f"removed {removed} teleport frame(s)")


def _fill_gaps(arrays: dict, valid: NDArray, actions: list[str]) -> None:
    seen = np.flatnonzero(valid)
    if seen.size == 0:
        return
    filled = 0
    for start, stop in _runs(~valid):
        if start == 0 or stop == len(valid) or stop - start > MAX_REPAIR_GAP_FRAMES:
            continue
        frames = np.arange(start, stop)
        for name, values in arrays.items():
            if name == "yaw_rad":
                unwrapped = np.unwrap([values[start - 1], values[stop]])
                values[frames] = wrap_angle(np.interp(frames, [start - 1, stop], unwrapped))
            else:
                values[frames] = np.interp(
                    frames, [start - 1, stop], [values[start - 1], values[stop]]
                )
        valid[frames] = True
        filled += 1
    if filled:
        actions.append(f"interpolated {filled} gap(s) of at most {MAX_REPAIR_GAP_FRAMES / 10:g} s")


def _motion_heading(arrays: dict, valid: NDArray) -> tuple[NDArray, NDArray]:
    """Direction and speed of motion per frame from central differences of positions."""
    x, y = arrays["x_m"], arrays["y_m"]
    dx, dy = np.full(len(x), np.nan), np.full(len(x), np.nan)
    for k in np.flatnonzero(valid):
        before = k - 1 if k > 0 and valid[k - 1] else k
        after = k + 1 if k + 1 < len(x) and valid[k + 1] else k
        if after != before:
            dx[k] = (x[after] - x[before]) / ((after - before) * FRAME_S)
            dy[k] = (y[after] - y[before]) / ((after - before) * FRAME_S)
    return np.arctan2(dy, dx), np.hypot(dx, dy)


def _flip_reversed(track: Track, arrays: dict, valid: NDArray, actions: list[str]) -> None:
    if track.agent_class == AgentClass.PEDESTRIAN:
        return  # people walk backwards sometimes; their yaw is not a vehicle's
    direction, speed = _motion_heading(arrays, valid)
    against = np.abs(wrap_angle(arrays["yaw_rad"] - direction)) > REVERSED_HEADING_RAD
    reversed_ = np.zeros(len(valid), bool)
    for start, stop in _runs(valid & (speed > FLIP_MPS) & against):
        if stop - start >= FLIP_MIN_FRAMES:
            reversed_[start:stop] = True
    if reversed_.any():
        arrays["yaw_rad"][reversed_] = wrap_angle(arrays["yaw_rad"][reversed_] + np.pi)
        actions.append(f"flipped a reversed heading in {int(reversed_.sum())} frame(s)")


def _moving_average(values: NDArray) -> NDArray:
    return np.convolve(np.pad(values, 2, mode="edge"), np.ones(5) / 5, mode="valid")


def jitter_m(arrays: dict, valid: NDArray) -> float:
    """RMS distance (m) of positions from their centred 5-frame mean, over runs of valid frames:
    shaking, not turning or braking, which a 5-frame mean follows."""
    residuals = []
    for start, stop in _runs(valid):
        if stop - start >= 5:
            x, y = arrays["x_m"][start:stop], arrays["y_m"][start:stop]
            residuals.append(np.hypot(x - _moving_average(x), y - _moving_average(y))[2:-2])
    if not residuals:
        return 0.0
    return float(np.sqrt(np.mean(np.concatenate(residuals) ** 2)))


def _smooth(arrays: dict, valid: NDArray, actions: list[str]) -> None:
    before = jitter_m(arrays, valid)
    if before <= JITTER_LIMIT_M:
        return
    smoothed = {name: arrays[name].copy() for name in ("x_m", "y_m")}
    for start, stop in _runs(valid):
        if stop - start >= 5:
            for name in smoothed:
                smoothed[name][start:stop] = _moving_average(smoothed[name][start:stop])
    after = jitter_m({**arrays, **smoothed}, valid)
    if after < before:
        arrays.update(smoothed)
        actions.append(f"smoothed jitter of {before:.2f} m to {after:.2f} m")


def _plausibility(track: Track, arrays: dict, valid: NDArray) -> float:
    _, speed = _motion_heading(arrays, valid)
    speed_ok = np.nan_to_num(speed, nan=0.0)[valid] <= MAX_SPEED_MPS[track.agent_class]
    accel = np.abs(np.diff(speed)) / FRAME_S
    accel_ok = np.nan_to_num(accel, nan=0.0)[valid[1:] & valid[:-1]] <= MAX_ACCEL_MPS2
    return float(
        min(speed_ok.mean() if speed_ok.size else 1.0, accel_ok.mean() if accel_ok.size else 1.0)
    )


def _compliance(
    track: Track, arrays: dict, valid: NDArray, intersection_map: IntersectionMap | None
) -> float:
    if intersection_map is None or not track.agent_class.is_motor_vehicle:
        return 1.0
    frames = np.flatnonzero(valid)
    points = shapely.points(arrays["x_m"][frames], arrays["y_m"][frames])
    road = _road(intersection_map)
    off_road = shapely.distance(road, points) > OFF_ROAD_M
    direction, speed = _motion_heading(arrays, valid)
    moving = speed[frames] > MOVING_MPS
    near_any = np.zeros(len(frames), bool)
    aligned_any = np.zeros(len(frames), bool)
    for lane in intersection_map.lanes:
        line = shapely.LineString(lane.centerline_m[:, :2])
        near = moving & (shapely.distance(line, points) < LANE_MATCH_M)
        if not near.any():
            continue
        s = shapely.line_locate_point(line, points[near])
        a = shapely.get_coordinates(shapely.line_interpolate_point(line, np.maximum(s - 0.5, 0.0)))
        b = shapely.get_coordinates(
            shapely.line_interpolate_point(line, np.minimum(s + 0.5, line.length))
        )
        heading = np.arctan2(b[:, 1] - a[:, 1], b[:, 0] - a[:, 0])
        aligned = np.abs(wrap_angle(direction[frames][near] - heading)) <= AGAINST_LANE_RAD
        near_any |= near
        aligned_any[np.flatnonzero(near)[aligned]] = True
    against = near_any & ~aligned_any
    return float(1.0 - max(off_road.mean(), against.mean()))


_ROAD_CACHE: dict[int, shapely.Geometry] = {}


def _road(intersection_map: IntersectionMap) -> shapely.Geometry:
    key = id(intersection_map)
    if key not in _ROAD_CACHE:
        pieces = [
            shapely.make_valid(shapely.Polygon(c.polygon_m)) for c in intersection_map.crosswalks
        ]
        _ROAD_CACHE.clear()
        _ROAD_CACHE[key] = shapely.union_all([intersection_map.drivable_union(), *pieces])
    return _ROAD_CACHE[key]


def assess_track(
    track: Track, intersection_map: IntersectionMap | None = None
) -> tuple[Track | None, TrackQuality]:
    """The repaired track (None when dropped) and its quality."""
    arrays = _arrays(track)
    valid = np.array(track.valid)
    actions: list[str] = []
    _remove_teleports(track, arrays, valid, actions)
    _fill_gaps(arrays, valid, actions)
    _flip_reversed(track, arrays, valid, actions)
    _smooth(arrays, valid, actions)
    seen = np.flatnonzero(valid)
    span = (seen[-1] - seen[0] + 1) if seen.size else 1
    completeness = float(seen.size / span) if seen.size >= MIN_FRAMES else 0.0
    plausibility = _plausibility(track, arrays, valid) if seen.size else 0.0
    compliance = _compliance(track, arrays, valid, intersection_map) if seen.size else 0.0
    score = completeness * plausibility * compliance
    quality = TrackQuality(track.track_id, score, completeness, plausibility, compliance, actions)
    if score < MIN_SCORE:
        quality.dropped = True
        quality.actions.append(f"dropped: score {score:.2f} < {MIN_SCORE}")
        return None, quality
    direction, speed = _motion_heading(arrays, valid)
    if actions:  # velocities follow the repaired positions
        arrays["vx_mps"] = np.where(valid, np.nan_to_num(speed * np.cos(direction)), np.nan)
        arrays["vy_mps"] = np.where(valid, np.nan_to_num(speed * np.sin(direction)), np.nan)
    metadata = {**track.metadata, "quality": f"{score:.3f}"}
    repaired = Track(track.track_id, track.agent_class, valid=valid, metadata=metadata, **arrays)
    return repaired, quality


def assess_scenario(
    scenario: Scenario, intersection_map: IntersectionMap | None = None
) -> tuple[list[Track], list[TrackQuality]]:
    """Every track assessed; the kept (repaired) tracks and every track's quality."""
    kept, qualities = [], []
    for track in scenario.tracks:
        repaired, quality = assess_track(track, intersection_map)
        qualities.append(quality)
        if repaired is not None:
            kept.append(repaired)
    return kept, qualities
