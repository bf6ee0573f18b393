"""Cutting long recordings (drone and infrastructure data) into clips.

Two ways: `cut_ego_clips`, the default, gives a clip per usable ego: every motor vehicle that
passes through the junction area gets a clip spanning its approach, passage and exit, within
a minimum and maximum length, overlaps allowed and reported; `cut_clips` gives consecutive
fixed windows, each taking the first vehicle valid throughout as its ego (if any).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from datetime import timedelta

import numpy as np
import shapely

from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.scenario import FRAME_PERIOD_NS, TRACK_ARRAYS, Scenario, Track

CUT_MODES = ("ego", "windows")
APPROACH_S = 8.0  # an ego's clip starts this long before it enters the junction (if seen)
EXIT_S = 5.0  # ... and ends this long after it leaves
MIN_CLIP_S = 10.0
MAX_CLIP_S = 30.0
JUNCTION_OVERLAP_M2 = 2.0  # lanes whose surfaces overlap this much cross: they form the junction
JUNCTION_MERGE_M = 3.0  # crossings this close together belong to one junction


@dataclass
class CutReport:
    """What ego-first cutting found: candidates, clips, why others were left out, overlaps."""

    candidates: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    overlapping_pairs: int = 0
    mean_overlap_share: float = 0.0  # per clip, the largest share of it another clip also covers
    fallback: str | None = None  # why fixed windows were used instead, if they were

    def skip(self, reason: str) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + 1

    def lines(self) -> list[str]:
        if self.fallback:
            return [f"  fixed windows: {self.fallback}"]
        rows = [f"  {self.candidates} vehicles pass through the junction"]
        rows += [f"  left out ({n}): {why}" for why, n in sorted(self.skipped.items())]
        rows.append(
            f"  {self.overlapping_pairs} overlapping clip pairs; a clip shares "
            f"{100 * self.mean_overlap_share:.0f}% of its frames with its most overlapping "
            "neighbour on average"
        )
        return rows


def junction_area(intersection_map: IntersectionMap) -> shapely.Geometry | None:
    """Where lanes cross: the union of the junction lanes, or, for maps that flag none
    (Lanelet2), the hull of each cluster of places where a lane's surface overlaps one it does
    not continue or neighbour. None when the map shows no junction."""
    flagged = [lane.polygon() for lane in intersection_map.lanes if lane.is_intersection]
    if flagged:
        return shapely.union_all(flagged)
    lanes = [lane for lane in intersection_map.lanes if lane.lane_type.value == "vehicle"]
    polygons = [lane.polygon() for lane in lanes]
    tree = shapely.STRtree(polygons)
    overlaps = []
    for i, j in zip(*tree.query(polygons, predicate="intersects"), strict=True):
        a, b = lanes[i], lanes[j]
        related = {*a.predecessors, *a.successors, a.left_neighbor, a.right_neighbor}
        if i >= j or b.lane_id in related or a.lane_id in {*b.predecessors, *b.successors}:
            continue
        overlap = polygons[i].intersection(polygons[j])
        if overlap.area > JUNCTION_OVERLAP_M2:
            overlaps.append(overlap)
    if not overlaps:
        return None
    # the crossings of one junction lie close together: each cluster's hull is a junction
    clusters = shapely.union_all(overlaps).buffer(JUNCTION_MERGE_M)
    parts = getattr(clusters, "geoms", [clusters])
    return shapely.union_all([part.convex_hull.buffer(-JUNCTION_MERGE_M) for part in parts])


def cut_ego_clips(
    scenario: Scenario,
    intersection_map: IntersectionMap,
    min_s: float = MIN_CLIP_S,
    max_s: float = MAX_CLIP_S,
) -> tuple[list[Scenario], CutReport]:
    """A clip per motor vehicle that passes through the junction area: from `APPROACH_S` before
    it enters to `EXIT_S` after it leaves, lengthened within its visibility to `min_s`,
    shortened from the approach side to `max_s`; the vehicle is valid throughout and the clip's
    ego. Clips are named `<recording>_<track id>`, ordered by start."""
    report = CutReport()
    junction = junction_area(intersection_map)
    if junction is None:
        report.fallback = "the map shows no junction"
        return [], report
    shapely.prepare(junction)
    frame_s = FRAME_PERIOD_NS / 1e9
    min_frames, max_frames = round(min_s / frame_s), round(max_s / frame_s)
    windows: list[tuple[int, int, Track]] = []
    for track in scenario.tracks:
        if not track.agent_class.is_motor_vehicle:
            continue
        inside = track.valid.copy()
        inside[track.valid] = shapely.contains_xy(
            junction, track.x_m[track.valid], track.y_m[track.valid]
        )
        if not inside.any():
            continue
        report.candidates += 1
        window = _window(track.valid, inside, min_frames, max_frames, frame_s)
        if isinstance(window, str):
            report.skip(window)
        else:
            windows.append((*window, track))
    windows.sort(key=lambda w: (w[0], w[2].track_id))
    clips = [_clip(scenario, start, stop, track.track_id) for start, stop, track in windows]
    _report_overlaps(windows, report)
    return clips, report


def _window(
    valid: np.ndarray, inside: np.ndarray, min_frames: int, max_frames: int, frame_s: float
) -> tuple[int, int] | str:
    """[start, stop) of an ego's clip, or why it has none."""
    first_in = int(np.argmax(inside))
    run_start = first_in
    while run_start > 0 and valid[run_start - 1]:
        run_start -= 1
    run_stop = first_in
    while run_stop < len(valid) and valid[run_stop]:
        run_stop += 1
    last_in = first_in + int(np.flatnonzero(inside[first_in:run_stop])[-1])
    if run_start == first_in:
        return "already in the junction when the recording first shows it"
    if last_in == run_stop - 1:
        return "still in the junction when the recording last shows it"
    start = max(run_start, first_in - round(APPROACH_S / frame_s))
    stop = min(run_stop, last_in + 1 + round(EXIT_S / frame_s))
    if stop - start < min_frames:  # lengthen: more approach first, then more exit
        start = max(run_start, stop - min_frames)
        stop = min(run_stop, start + min_frames)
    if stop - start < min_frames:
        return f"seen for less than {min_frames * frame_s:.0f} s around its passage"
    if stop - start > max_frames:
        start = stop - max_frames
        if start > first_in:
            return f"its passage lasts more than {max_frames * frame_s:.0f} s"
    return start, stop


def _clip(scenario: Scenario, start: int, stop: int, ego_id: str) -> Scenario:
    window = slice(start, stop)
    return Scenario(
        scenario_id=f"{scenario.scenario_id}_{ego_id}",
        map_id=scenario.map_id,
        source=scenario.source,
        t_ns=scenario.t_ns[window],
        tracks=tuple(_slice_track(t, window) for t in scenario.tracks if t.valid[window].any()),
        signals=tuple(type(s)(s.signal_id, s.states[window], s.origin) for s in scenario.signals),
        conditions=_conditions_from(scenario, start),
        ego_id=ego_id,
        metadata={**scenario.metadata, "cut": "ego-first", "clip_first_frame": start},
    )


def _conditions_from(scenario: Scenario, first_frame: int):
    """The recording's conditions with the start moved to `first_frame`."""
    elapsed_us = int(scenario.t_ns[first_frame] - scenario.t_ns[0]) // 1000
    return replace(
        scenario.conditions,
        start_time_utc=scenario.conditions.start_time_utc + timedelta(microseconds=elapsed_us),
    )


def _report_overlaps(windows: list[tuple[int, int, Track]], report: CutReport) -> None:
    shares = []
    for index, (start, stop, _) in enumerate(windows):
        largest = 0
        for other, (other_start, other_stop, _) in enumerate(windows):
            if other != index:
                largest = max(largest, min(stop, other_stop) - max(start, other_start))
        shares.append(max(largest, 0) / (stop - start))
    report.overlapping_pairs = sum(
        1
        for i, (a_start, a_stop, _) in enumerate(windows)
        for b_start, b_stop, _ in windows[i + 1 :]
        if min(a_stop, b_stop) > max(a_start, b_start)
    )
    report.mean_overlap_share = float(np.mean(shares)) if shares else 0.0


def cut_clips(
    scenario: Scenario, clip_s: float, ego_candidates: Sequence[str] = ()
) -> list[Scenario]:
    """Cut a long recording into consecutive clips of `clip_s` seconds (the last may be shorter
    but at least half as long). A clip keeps the tracks valid in it; when `ego_candidates` are
    given, each clip's ego is the first candidate valid in every frame of it, if any."""
    frames = round(clip_s * 1e9 / FRAME_PERIOD_NS)
    clips = []
    for index, start in enumerate(range(0, scenario.num_frames, frames)):
        stop = min(start + frames, scenario.num_frames)
        if stop - start < max(2, frames // 2):
            break
        window = slice(start, stop)
        tracks = [_slice_track(t, window) for t in scenario.tracks if t.valid[window].any()]
        ego = next(
            (c for c in ego_candidates for t in tracks if t.track_id == c and t.valid.all()), None
        )
        clips.append(
            Scenario(
                scenario_id=f"{scenario.scenario_id}_{index:03d}",
                map_id=scenario.map_id,
                source=scenario.source,
                t_ns=scenario.t_ns[window],
                tracks=tuple(tracks),
                signals=tuple(
                    type(s)(s.signal_id, s.states[window], s.origin) for s in scenario.signals
                ),
                conditions=_conditions_from(scenario, start),
                ego_id=ego,
                metadata={**scenario.metadata, "clip_index": index, "clip_first_frame": start},
            )
        )
    return clips


def _slice_track(track: Track, window: slice) -> Track:
    arrays = {name: getattr(track, name)[window] for name in (*TRACK_ARRAYS, "valid")}
    return replace(track, **arrays)
