"""The synthetic source: determinism, layouts, staged behaviours and the physics of its traffic."""

from pathlib import Path

import numpy as np
import pytest
import shapely

from drivee2e_data import pipeline, store
from drivee2e_data.geometry import box_corners_2d, boxes_overlap
from drivee2e_data.scenario import AgentClass, BehaviorCategory, SignalState
from drivee2e_data.sources import synthetic
from tests.factories import assert_sun_matches_label

MAX_VEHICLE_SPEED_MPS = 20.0  # 72 km/h: well above the 50 km/h limit of the synthetic roads
MAX_VEHICLE_ACCEL_MPS2 = 8.5  # emergency braking is capped at 8 m/s^2 in the traffic model
MAX_PEDESTRIAN_SPEED_MPS = 2.5


def _files(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


@pytest.mark.slow
def test_same_seed_gives_identical_files(synthetic_root: Path, tmp_path: Path):
    """The first three clips of the default set, made again in a fresh run, are byte-identical."""
    pipeline.synthesize(tmp_path / "again", clips=3, seed=0)
    again = _files(tmp_path / "again")
    assert again and all(name.endswith((".json", ".parquet")) for name in again)
    original = _files(synthetic_root)
    for name, content in again.items():
        assert original[name] == content, name


@pytest.mark.slow
def test_other_seed_gives_other_files(synthetic_root: Path, tmp_path: Path):
    pipeline.synthesize(tmp_path / "seed1", clips=1, seed=1)
    seed1 = _files(tmp_path / "seed1")
    seed0 = _files(synthetic_root)
    tracks0 = seed0["scenarios/synth_s0_c0000/tracks.parquet"]
    tracks1 = seed1["scenarios/synth_s1_c0000/tracks.parquet"]
    assert tracks0 != tracks1
    assert seed0["maps/synth_s0_i00.json"] != seed1["maps/synth_s1_i00.json"]


@pytest.mark.slow
def test_only_some_clips_are_the_whole_sets_files(synthetic_root: Path, tmp_path: Path, capsys):
    """`synth --only` writes the named clips of the set and nothing else, each byte-identical
    to the whole set's; a clip outside the set is one clear error."""
    from drivee2e_data.cli import main

    out = tmp_path / "some"
    args = ["synth", "--out", str(out), "--clips", "12", "--seed", "0"]
    assert main([*args, "--only", "synth_s0_c0005", "synth_s0_c0002"]) == 0
    some, original = _files(out), _files(synthetic_root)
    assert sorted(store.scenario_ids(out)) == ["synth_s0_c0002", "synth_s0_c0005"]
    assert {name for name in some if name.startswith("maps/")} == {
        name for name in original if name.startswith("maps/")
    }
    for name, content in some.items():
        assert original[name] == content, name
    assert main([*args, "--only", "synth_s0_c0012"]) != 0
    error = capsys.readouterr().err
    assert "synth_s0_c0012" in error and "is not one of the 12 clips of seed 0" in error


def test_rerun_skips_finished_clips(synthetic_root: Path):
    before = {p: p.stat().st_mtime_ns for p in synthetic_root.rglob("*.parquet")}
    report = pipeline.synthesize(synthetic_root, clips=2, seed=0)
    assert report.written == [] and len(report.skipped) == 2
    assert {p: p.stat().st_mtime_ns for p in synthetic_root.rglob("*.parquet")} == before


@pytest.mark.slow
def test_layouts_cover_three_and_four_way_with_one_to_three_lanes():
    sites = [synthetic.make_site(7, index) for index in range(10)]
    arm_counts = {len(site.layout.arms) for site in sites}
    lane_counts = {arm.lanes_in for site in sites for arm in site.layout.arms}
    assert arm_counts == {3, 4}
    assert lane_counts == {1, 2, 3}
    for site in sites:
        m = site.intersection_map
        arms = len(site.layout.arms)
        assert len(m.crosswalks) == arms and len(m.stop_lines) == arms
        assert m.buildings and m.trees and len(m.sidewalks) >= arms - 1
        assert any(lane.turn_direction.value == "u_turn" for lane in m.lanes)
        skew = [abs(np.rad2deg(a.angle_rad) % 90) for a in site.layout.arms]
        assert any(1.0 < s < 89.0 for s in skew)
        # protected and permissive lefts both exist at each site
        assert any(site.layout.protected_left) and not all(site.layout.protected_left)


def test_every_category_occurs_in_the_default_set(synthetic_scenarios):
    categories = {s.behavior.category for s in synthetic_scenarios}
    assert categories == set(BehaviorCategory)
    assert all(s.behavior.source == "staged" for s in synthetic_scenarios)


def test_the_sun_matches_every_clips_time_of_day(synthetic_root: Path, synthetic_scenarios):
    for scenario in synthetic_scenarios:
        origin = store.read_map(synthetic_root, scenario.map_id).origin
        assert_sun_matches_label(scenario.conditions, origin)
    assert len({s.conditions.time_of_day for s in synthetic_scenarios}) >= 4


def test_all_eight_classes_appear(synthetic_scenarios):
    present = {t.agent_class for s in synthetic_scenarios for t in s.tracks}
    assert present == set(AgentClass)


def test_clips_are_15_to_30_s_and_ego_valid_throughout(synthetic_scenarios):
    for scenario in synthetic_scenarios:
        assert 15.0 <= scenario.duration_s <= 30.0, scenario.scenario_id
        assert scenario.ego.valid.all(), scenario.scenario_id
        assert scenario.ego.agent_class.is_motor_vehicle
        assert scenario.route is not None and len(scenario.route.waypoints_xy_m) >= 2


def _vehicle_tracks(scenario):
    return [t for t in scenario.tracks if t.agent_class != AgentClass.PEDESTRIAN]


def test_no_two_agents_overlap_in_any_frame(synthetic_scenarios):
    """Vehicles and pedestrians alike: two walkers in each other's box at a kerb made one hide
    the other while its label said it was seen."""
    for scenario in synthetic_scenarios:
        tracks = list(scenario.tracks)
        for frame in range(scenario.num_frames):
            alive = [t for t in tracks if t.valid[frame]]
            corners = np.stack(
                [
                    box_corners_2d(
                        t.xy_m[frame], t.yaw_rad[frame], t.length_m[frame], t.width_m[frame]
                    )
                    for t in alive
                ]
            )
            i, j = np.triu_indices(len(alive), 1)
            overlapping = boxes_overlap(corners[i], corners[j])
            pairs = [
                (alive[a].track_id, alive[b].track_id)
                for a, b in zip(i[overlapping], j[overlapping], strict=True)
            ]
            assert not pairs, f"{scenario.scenario_id} frame {frame}: {pairs}"


def test_no_vehicle_enters_on_red(synthetic_root: Path, synthetic_scenarios):
    checked = 0
    for scenario in synthetic_scenarios:
        intersection_map = store.read_map(synthetic_root, scenario.map_id)
        stop_line_of = {lane: s for s in intersection_map.stop_lines for lane in s.lane_ids}
        for track in _vehicle_tracks(scenario):
            entry_lane = track.metadata["lanes"].split(",")[0]
            line = shapely.LineString(stop_line_of[entry_lane].line_m[:, :2])
            states = scenario.signal(track.metadata["signal"]).states
            front = track.xy_m + 0.5 * track.length_m[:, None] * np.stack(
                [np.cos(track.yaw_rad), np.sin(track.yaw_rad)], -1
            )
            for frame in range(scenario.num_frames - 1):
                if not (track.valid[frame] and track.valid[frame + 1]):
                    continue
                if shapely.LineString(front[frame : frame + 2]).intersects(line):
                    checked += 1
                    assert states[frame + 1] != SignalState.RED, (
                        f"{scenario.scenario_id}: {track.track_id} crossed its stop line on red "
                        f"at frame {frame + 1}"
                    )
    assert checked > 20  # the check saw plenty of stop-line crossings


def test_speeds_and_accelerations_are_plausible(synthetic_scenarios):
    for scenario in synthetic_scenarios:
        for track in scenario.tracks:
            both = track.valid[1:] & track.valid[:-1]
            speed = np.linalg.norm(np.diff(track.xy_m, axis=0), axis=1)[both] / 0.1
            logged = track.speed_mps[track.valid]
            if track.agent_class == AgentClass.PEDESTRIAN:
                assert logged.max() <= MAX_PEDESTRIAN_SPEED_MPS
                continue
            assert speed.max(initial=0) <= MAX_VEHICLE_SPEED_MPS, track.track_id
            three = track.valid[2:] & track.valid[1:-1] & track.valid[:-2]
            accel = np.diff(np.linalg.norm(np.diff(track.xy_m, axis=0), axis=1) / 0.1) / 0.1
            assert np.abs(accel[three]).max(initial=0) <= MAX_VEHICLE_ACCEL_MPS2, (
                f"{scenario.scenario_id} {track.track_id}"
            )


def test_pedestrians_step_onto_the_road_only_on_walk(synthetic_root: Path, synthetic_scenarios):
    stepped = 0
    for scenario in synthetic_scenarios:
        road = store.read_map(synthetic_root, scenario.map_id).drivable_union().buffer(-0.3)
        for track in scenario.tracks:
            if track.agent_class != AgentClass.PEDESTRIAN or track.metadata["jaywalks"] == "true":
                continue
            on_road = shapely.contains_xy(road, track.x_m, track.y_m) & track.valid
            entries = np.flatnonzero(on_road[1:] & ~on_road[:-1] & track.valid[:-1]) + 1
            signal = scenario.signal("ped_" + track.metadata["crossing"].split("_")[1])
            for frame in entries:
                stepped += 1
                recent = signal.states[max(0, frame - 5) : frame + 1]
                assert (recent == SignalState.GREEN).any(), (
                    f"{scenario.scenario_id} {track.track_id}"
                )
    assert stepped > 5


@pytest.mark.parametrize("clips", [0, -1])
def test_synthesize_rejects_bad_counts(tmp_path: Path, clips: int):
    with pytest.raises(ValueError, match="clips must be at least 1"):
        pipeline.synthesize(tmp_path, clips=clips, seed=0)


@pytest.mark.slow
def test_a_target_the_site_cannot_stage_falls_back_to_the_next() -> None:
    """Clip 91 of seed 0 targets COV-LFT on a site with no conflict to stage it (found making
    the 800-clip benchmark set): it takes the next target instead of stopping the run."""
    site = synthetic.make_site(0, 1)
    scenario = synthetic.generate_clip(site, 0, 91)
    assert synthetic.TARGET_ORDER[91 % len(synthetic.TARGET_ORDER)].value == "COV-LFT"
    assert scenario.metadata["target_sub_scenario"] == "YLW-LFT"
    assert scenario.behavior is not None


def test_a_walkers_interpolation_is_numpys_to_the_bit():
    """The traffic step interpolates walkers on plain floats (`traffic._interp`) for speed; it
    gives `np.interp`'s value to the bit: inside a leg, at a sample (a repeated one too: the
    later leg's), before the first and past the last sample."""
    from drivee2e_data.sources.synthetic.traffic import _interp

    rng = np.random.default_rng(11)
    checked = 0
    for trial in range(300):
        count = int(rng.integers(2, 8))
        xp = np.concatenate([[0.0], np.cumsum(rng.uniform(0.0, 5.0, count - 1))])
        if trial % 4 == 0 and count > 2:
            xp[2] = xp[1]  # a leg of no length
        fp = rng.uniform(-100.0, 100.0, count)
        queries = np.concatenate([rng.uniform(-2.0, xp[-1] + 2.0, 20), xp, [xp[-1], -0.0]])
        for x in queries:
            assert _interp(float(x), xp.tolist(), fp.tolist()) == float(np.interp(x, xp, fp))
            checked += 1
    assert checked > 7000
    assert _interp(1.0, [0.0, 1.0, 1.0, 2.0], [0.0, 5.0, 7.0, 9.0]) == 7.0  # the later leg's
    assert _interp(0.5, [0.0, 1.0], [2.0, 4.0]) == 3.0
    assert (
        _interp(-1.0, [0.0, 1.0], [2.0, 4.0]) == 2.0 and _interp(3.0, [0.0, 1.0], [2.0, 4.0]) == 4.0
    )
