"""Cutting long recordings: a clip per vehicle passing through the junction, or fixed windows."""

import numpy as np
import pytest
import shapely

from drivee2e_data import pipeline, store
from drivee2e_data.cli import main
from drivee2e_data.hdmap import IntersectionMap, Lane
from drivee2e_data.scenario import FRAME_PERIOD_NS, AgentClass, Scenario
from drivee2e_data.sources.cutting import cut_clips, cut_ego_clips, junction_area
from tests.factories import T0_NS, small_map, small_scenario, straight_track


@pytest.mark.slow
def test_a_recording_gives_a_clip_per_ego_three_times_the_windows(tmp_path):
    from drivee2e_data.sources.synthetic.recording import generate_recording

    site, recording = generate_recording(0, 0, 60.0)
    assert recording.ego_id is None and recording.num_frames == 601
    # cut and written as `synth --recording-seconds 60` does (`pipeline.synthesize_recording`;
    # the command itself runs below with `--cut windows`), without making the recording again
    recording_root = tmp_path / "recording"
    pieces, _ = pipeline.split_recording(recording, site.intersection_map, 20.0, "ego")
    store.write_map(recording_root, site.intersection_map)
    for piece in pieces:
        store.write_scenario(recording_root, piece)
    windows = cut_clips(recording, 20.0, [t.track_id for t in recording.tracks])
    with_ego = [clip for clip in windows if clip.ego_id is not None]
    clips = store.scenario_ids(recording_root)
    assert len(clips) >= 3 * len(with_ego) and len(with_ego) >= 1
    junction = junction_area(site.intersection_map)
    for scenario_id in clips:
        clip = store.read_scenario(recording_root, scenario_id)
        assert scenario_id == f"{recording.scenario_id}_{clip.ego_id}"
        ego = clip.ego
        assert ego.valid.all() and ego.agent_class.is_motor_vehicle
        assert 10.0 <= clip.duration_s <= 30.0
        inside = shapely.contains_xy(junction, ego.x_m, ego.y_m)
        assert inside.any() and not inside[0] and not inside[-1]  # approach, passage, exit
        first = clip.metadata["clip_first_frame"]
        source = recording.track(ego.track_id)
        assert np.array_equal(ego.x_m, source.x_m[first : first + clip.num_frames])
    rows = pipeline.curate(recording_root)
    assert all(row.behavior != "-" and row.ego_source == "kept from the source" for row in rows)
    windowed = tmp_path / "windows"
    assert (
        main(["synth", "--out", str(windowed), "--recording-seconds", "60", "--cut", "windows"])
        == 0
    )
    assert len(store.scenario_ids(windowed)) == len(windows)


def _crossing_map() -> IntersectionMap:
    """Two 3.5 m lanes crossing at the origin: the junction is their 3.5 m x 3.5 m overlap."""
    east = np.array([[-60.0, 0.0, 0.0], [60.0, 0.0, 0.0]])
    north = np.array([[0.0, -60.0, 0.0], [0.0, 60.0, 0.0]])
    across = np.array([0.0, 1.75, 0.0])
    up = np.array([1.75, 0.0, 0.0])
    lanes = (
        Lane("east", east, east + across, east - across),
        Lane("north", north, north - up, north + up),
    )
    return small_map(lanes=lanes, signal_heads=())


def _recording(tracks, frames: int) -> Scenario:
    return Scenario(
        scenario_id="rec",
        map_id="tiny_map",
        source="test",
        t_ns=T0_NS + FRAME_PERIOD_NS * np.arange(frames, dtype=np.int64),
        tracks=tuple(tracks),
        signals=(),
        conditions=small_scenario().conditions,
    )


def _driving(track_id: str, frames: int, start_x: float, speed: float, first: int = 0):
    """A car driving east along y = 0 from `start_x` at `speed`, visible from frame `first`."""
    track = straight_track(track_id, frames, AgentClass.CAR)
    x = start_x + speed * 0.1 * (np.arange(frames) - first)
    valid = np.arange(frames) >= first
    return track.__class__(
        **{
            **{name: getattr(track, name) for name in track.__dataclass_fields__},
            "x_m": np.where(valid, x, np.nan),
            "y_m": np.where(valid, 0.0, np.nan),
            "valid": valid,
        }
    )


def test_junction_from_crossing_lanes_when_the_map_flags_none():
    junction = junction_area(_crossing_map())
    assert junction.area == pytest.approx(3.5 * 3.5, abs=0.01)  # buffered out and back in
    assert junction.contains(shapely.Point(0.0, 0.0))


def test_ego_windows_known_answers():
    frames = 600  # a 60 s recording
    # A at 5 m/s from x = -50: inside the junction (|x| < 1.75) in frames 97-103, so its clip
    # runs from 8 s before (frame 17) to 5 s after (frame 153): 137 frames
    fast = _driving("A", frames, -50.0, 5.0)
    # B enters at 1 s: already 8 s cannot be had, so its clip starts where it is first seen
    early = _driving("B", frames, -6.75, 5.0)
    # C waits 40 s in the junction: its passage is longer than 30 s
    stuck = _driving("C", frames, -20.0, 5.0)
    stuck_x = np.clip(stuck.x_m, None, 0.0)
    stuck_x[450:] = np.linspace(0.0, 60.0, frames - 450)
    stuck = stuck.__class__(
        **{**{n: getattr(stuck, n) for n in stuck.__dataclass_fields__}, "x_m": stuck_x}
    )
    # D is in the junction when first seen
    inside = _driving("D", frames, 0.0, 5.0, first=100)
    clips, report = cut_ego_clips(_recording([fast, early, stuck, inside], frames), _crossing_map())
    by_ego = {clip.ego_id: clip for clip in clips}
    assert set(by_ego) == {"A", "B"}
    a = by_ego["A"]
    assert a.metadata["clip_first_frame"] == 17 and a.num_frames == 137
    b = by_ego["B"]
    assert b.metadata["clip_first_frame"] == 0 and b.num_frames == 100  # lengthened to 10 s
    assert report.candidates == 4 and sum(report.skipped.values()) == 2
    assert report.overlapping_pairs == 1
