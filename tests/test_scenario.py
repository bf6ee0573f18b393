import numpy as np
import pytest
from factories import T0_NS, small_map, small_scenario, straight_track

from drivee2e_data.errors import MapFormatError, ScenarioFormatError
from drivee2e_data.hdmap import Lane
from drivee2e_data.scenario import AgentClass, SignalTimeline, SubScenario


def test_valid_scenario_builds_and_compares_by_value():
    scenario = small_scenario()
    assert scenario.num_frames == 5
    assert scenario.duration_s == pytest.approx(0.4)
    assert scenario.ego.track_id == "a"
    assert scenario == small_scenario()
    assert scenario != small_scenario(ego_id="b")
    assert scenario.class_counts()[AgentClass.PEDESTRIAN] == 1


def test_arrays_are_read_only():
    track = straight_track()
    with pytest.raises(ValueError):
        track.x_m[0] = 5.0


def test_nan_position_names_track_field_and_frame():
    x = np.arange(5.0)
    x[3] = np.nan
    with pytest.raises(ScenarioFormatError, match=r"track 'a': x_m is nan at frame 3"):
        straight_track(x_m=x)


def test_nan_where_invalid_is_allowed():
    x = np.arange(5.0)
    x[3] = np.nan
    valid = np.array([True, True, True, False, True])
    assert not straight_track(x_m=x, valid=valid).valid[3]


def test_non_increasing_timestamp_is_rejected():
    t = T0_NS + 100_000_000 * np.array([0, 1, 2, 2, 4])
    with pytest.raises(ScenarioFormatError, match=r"t_ns: not strictly increasing at frame 3"):
        small_scenario(t_ns=t)


def test_timeline_must_be_10_hz():
    t = T0_NS + 50_000_000 * np.arange(5)
    with pytest.raises(ScenarioFormatError, match=r"expected 100000000 \(10 Hz\)"):
        small_scenario(t_ns=t)


def test_duplicate_track_id_is_rejected():
    with pytest.raises(ScenarioFormatError, match=r"track id 'a' at index 1 duplicates index 0"):
        small_scenario(tracks=(straight_track("a"), straight_track("a")))


def test_unknown_class_is_rejected():
    with pytest.raises(ScenarioFormatError, match="is not an AgentClass"):
        straight_track(agent_class="hovercraft")


def test_track_length_must_match_timeline():
    with pytest.raises(ScenarioFormatError, match=r"tracks\[0\] \('a'\): 4 frames, expected 5"):
        small_scenario(tracks=(straight_track("a", frames=4),))


def test_ego_must_be_a_track():
    with pytest.raises(ScenarioFormatError, match="ego_id: 'zz' is not a track"):
        small_scenario(ego_id="zz")


def test_unknown_signal_state_is_rejected():
    with pytest.raises(ScenarioFormatError, match="state 9 at frame 0"):
        SignalTimeline("s", np.array([9, 1], np.uint8))


def test_sub_scenarios_map_onto_the_eight_categories():
    assert len(SubScenario) == 14
    categories = {s.category.value for s in SubScenario}
    assert categories == {"IPC", "COV", "YLW", "UT", "STP", "STR", "LFT", "RT"}
    assert SubScenario.UT_AN.category.value == "UT"


def test_map_rejects_missing_lane_reference():
    lane = small_map().lanes[0]
    broken = Lane(
        "l2", lane.centerline_m, lane.left_boundary_m, lane.right_boundary_m, successors=("nope",)
    )
    with pytest.raises(MapFormatError, match=r"lane 'l2'.successors references lane 'nope'"):
        small_map(lanes=(lane, broken))


def test_map_rejects_duplicate_lane_and_bad_polyline():
    lane = small_map().lanes[0]
    with pytest.raises(MapFormatError, match="lane id 'l1' at index 1 is not unique"):
        small_map(lanes=(lane, lane))
    with pytest.raises(MapFormatError, match=r"lane 'x'.centerline_m: point 1 is not finite"):
        Lane("x", np.array([[0, 0], [np.nan, 1]]), lane.left_boundary_m, lane.right_boundary_m)


def test_map_rejects_signal_nobody_shows():
    lane = small_map().lanes[0]
    with pytest.raises(MapFormatError, match="signal 's1', which no head shows"):
        small_map(lanes=(lane,), signal_heads=())
