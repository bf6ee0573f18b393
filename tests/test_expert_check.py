"""The expert-replay check and what makes the expert clean: one collision definition shared by
staging and the rules, U-turns staged where they fit with pedestrians waiting at the corner,
the off-road measure on a wheel over a kerb, flagged clips left out of the splits."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import shapely

from drivee2e_data import splits, store
from drivee2e_data.agents.expert_check import check_clip
from drivee2e_data.cli import main
from drivee2e_data.collision import EXPERT_TRACKING_MARGIN_M, boxes_collide
from drivee2e_data.curation.replay_flags import METADATA_KEY, Flag, record, recorded_flags
from drivee2e_data.hdmap import TurnDirection
from drivee2e_data.metrics.closedloop import MapRules, wheel_points
from drivee2e_data.scenario import AgentClass, SignalState
from drivee2e_data.sensors.ego_state import ego_motion, to_ego_frame
from drivee2e_data.sim.vehicle import Bicycle, VehicleState, WaypointController
from drivee2e_data.sources import synthetic
from drivee2e_data.sources.synthetic import layout as layouts
from drivee2e_data.sources.synthetic.population import crossing_pedestrian, crosswalk_crossing
from drivee2e_data.sources.synthetic.staging import WARMUP_S, first_overlap
from drivee2e_data.sources.synthetic.traffic import TrafficSimulation, VehicleSpec
from tests.conftest import copy_clips
from tests.factories import small_scenario, straight_track
from tests.test_closedloop import FRAMES, parked, road_map, road_scenario, run


def test_the_grown_box_collides_where_the_plain_one_does_not() -> None:
    ego = (np.zeros(2), 0.0, np.array([4.0, 2.0]))
    beside = (np.array([0.0, 1.5]), 0.0, np.array([0.6, 0.6]))  # 0.2 m clear of the ego's side
    assert not boxes_collide(*ego, *beside)
    assert boxes_collide(*ego, *beside, margin_a_m=0.25)
    assert not boxes_collide(*ego, *beside, margin_a_m=0.15)


def test_pure_pursuit_holds_the_tightest_u_turn_loop() -> None:
    """The largest car on a loop of the smallest U-turn radius at 3 m/s, starting on the arc
    with its wheels straight: 3 s later its rear axle is within 5 cm of the arc and stays
    there (the old gain on the aim angle steered half the angle and swung wide)."""
    length = layouts.U_TURN_VEHICLE_M[0]
    bicycle = Bicycle(length, layouts.U_TURN_VEHICLE_M[1], 0.3 * length)
    controller = WaypointController(bicycle.wheelbase_m)
    radius = np.sqrt(layouts.u_turn_min_radius_m() ** 2 - (0.3 * length) ** 2)  # rear axle's
    state = VehicleState(radius, 0.0, np.pi / 2, 3.0)
    errors = []
    for step in range(60):
        angle = np.arctan2(state.y_m, state.x_m) + 1.5 / radius * np.arange(1, 7)
        ahead = radius * np.column_stack([np.cos(angle), np.sin(angle)])
        plan = to_ego_frame(ahead, state.x_m, state.y_m, state.yaw_rad)
        state = bicycle.step(state, controller.control(plan, state))
        if step >= 20:  # 2 s
            errors.append(abs(np.hypot(state.x_m, state.y_m) - radius))
    assert max(errors[10:]) < 0.05 and errors[-1] < 0.01
    assert abs(state.steer_rad) < layouts.U_TURN_STEER_SHARE * 0.6 + 0.02


def _kerb_run(y_m: float):
    ego = straight_track("ego", FRAMES, y_m=np.full(FRAMES, y_m))
    return run(small_scenario(FRAMES, tracks=(ego,), ego_id="ego", signals=road_scenario().signals))


def test_a_wheel_over_the_kerb_is_off_road_though_the_centre_is_on_it() -> None:
    """The road is 3.5 m wide (y within 1.75 m); a car 1.8 m wide has its wheels 0.7 m beside
    its centre line: at y = 1.5 m its left wheels run 0.45 m over the kerb, at y = 1.2 m 0.15 m
    (within the 0.25 m tolerance), at y = 0 not at all."""
    over = _kerb_run(1.5)
    assert over.off_road_percent > 90.0 and over.off_road_first_step == 1
    assert over.score.outside_lanes_percent >= over.off_road_percent and not over.score.success
    for y_m in (0.0, 1.2):
        within = _kerb_run(y_m)
        assert within.off_road_percent == 0.0 and within.score.success, y_m


def test_wheels_sit_at_the_axles_inset_from_the_sides() -> None:
    wheels = wheel_points(np.array([1.0, 2.0]), np.pi / 2, 2.7, 1.8)
    expected = [[0.3, 2.0], [0.3, 4.7], [1.7, 2.0], [1.7, 4.7]]
    assert np.allclose(sorted(wheels.tolist()), expected)


def test_a_path_clipping_a_pedestrian_is_flagged_with_its_frame_and_partner() -> None:
    """A pedestrian stands 1 m left of the ego's lane centre at x = 30 m: its box (0.6 m) and
    the ego's (1.8 m wide) overlap from the first frame the ego's front passes 29.7 m."""
    walker = dataclasses.replace(
        parked("walker", 30.0, AgentClass.PEDESTRIAN),
        y_m=np.full(FRAMES, 1.0),
        length_m=np.full(FRAMES, 0.6),
        width_m=np.full(FRAMES, 0.6),
    )
    scenario = road_scenario(walker)
    ego = scenario.track("ego")
    overlapping = [
        frame
        for frame in range(FRAMES)
        if boxes_collide(
            np.array([ego.x_m[frame], ego.y_m[frame]]),
            ego.yaw_rad[frame],
            np.array([4.5, 1.8]),
            np.array([30.0, 1.0]),
            0.0,
            np.array([0.6, 0.6]),
        )
    ]
    flags = check_clip(scenario, road_map())
    assert [(f.mode, f.rule, f.partner) for f in flags] == [
        ("log replay", "collision_pedestrian", "walker"),
        ("reactive", "collision_pedestrian", "walker"),
    ]
    assert {f.frame for f in flags} == {overlapping[0]} and overlapping[0] == 28
    assert check_clip(road_scenario(), road_map()) == ()


def test_flags_survive_the_bundle_and_an_older_version_counts_as_unchecked() -> None:
    flags = (Flag("reactive", "red_light", 40, "stop_a1"),)
    assert recorded_flags({METADATA_KEY: record(flags)}) == flags
    assert recorded_flags({METADATA_KEY: {"version": 0, "flags": []}}) is None
    assert recorded_flags({}) is None
    assert flags[0].line() == "red_light at frame 40 with stop_a1, reactive"


def test_every_u_turn_loop_keeps_its_clearance_and_its_wheel_angle() -> None:
    """On every site of the canonical set, each U-turn's loop swept by the largest car stays
    the expert's margin inside the kerbs, and its radius needs at most 85% of the lock."""
    smallest = layouts.u_turn_min_radius_m()
    assert 5.4 < smallest < 5.7  # a 4.97 m car, wheelbase 2.98 m, lock 0.6 rad
    u_turns = 0
    for index in range(3):
        site = synthetic.make_site(0, index)
        road = site.intersection_map.drivable_union()
        inside = road.buffer(-EXPERT_TRACKING_MARGIN_M + 1e-6)
        for movement in site.layout.movements:
            if movement.turn != TurnDirection.U_TURN:
                continue
            u_turns += 1
            assert layouts.sweeps_inside(movement.path_m, layouts.U_TURN_VEHICLE_M, inside)
            heading = np.unwrap(np.arctan2(*np.gradient(movement.path_m, axis=0).T[::-1]))
            curvature = np.abs(np.gradient(heading)) / layouts.CONNECTOR_SPACING_M
            assert np.convolve(curvature, np.ones(5) / 5, "valid").max() <= 1.05 / smallest
    assert u_turns >= 3


def test_a_u_turn_passes_pedestrians_waiting_at_its_corner() -> None:
    """A car U-turns on site 0 while walkers wait at both ends of its own arm's crosswalk (their
    light is red while its is green): no collision by the staged margin, its wheels on the
    carriageway, and the expert drives it cleanly in both modes."""
    site = synthetic.make_site(0, 0)
    movement = next(
        m for m in site.layout.movements if m.turn == TurnDirection.U_TURN and not m.abnormal
    )
    arm = site.layout.arms[movement.from_arm]
    path = site.network.paths[movement.movement_id]
    times = np.arange(WARMUP_S, WARMUP_S + site.plan.cycle_s, 0.5)
    green = [
        t for t in times
        if all(site.plan.states_at(t + d)[movement.signal_id] == SignalState.GREEN for d in range(8))
    ]  # fmt: skip
    arrival = float(green[0])
    speed = 9.0
    ego = VehicleSpec("v9999", AgentClass.CAR, movement.movement_id,
                      arrival - path.stop_s_m / speed, 4.97, 2.0, 1.5, speed)  # fmt: skip
    rng = np.random.default_rng(0)
    crossing = crosswalk_crossing(arm)
    along = arm.junction_edge_m + 0.5 * layouts.CROSSWALK_WIDTH_M
    walkers = [
        crossing_pedestrian(f"p{k}", arm, along + offset, from_left, arrival - 2.0, rng, crossing)
        for k, (offset, from_left) in enumerate(((-0.9, True), (0.9, False), (0.0, True)))
    ]
    horizon = arrival + 20.0
    result = TrafficSimulation(site.network, site.plan, [ego], walkers, horizon).run()
    first, last = round((arrival - 6.0) / 0.1), round((arrival + 14.0) / 0.1)
    window = slice(first, last + 1)
    # the walkers wait at the kerb while the car turns
    road = site.intersection_map.drivable_union()
    turning = np.flatnonzero(result.s_m[0, window] > path.stop_s_m)[:60] + first
    for row in (1, 2, 3):
        assert (result.speed_mps[row, turning] < 0.1).all()
        kerb = [road.exterior.distance(shapely.Point(result.x_m[row, s], result.y_m[row, s]))
                for s in turning]  # fmt: skip
        assert max(kerb) < 1.0
    assert first_overlap(result, [ego], walkers, first, last, ego_row=0) is None
    tracks, signals = synthetic.simulated_tracks(site, result, [ego], walkers, window)
    scenario = small_scenario(
        last - first + 1, scenario_id="u_turn", map_id=site.intersection_map.map_id,
        tracks=tracks, signals=signals, ego_id="v0000",
    )  # fmt: skip
    scenario = dataclasses.replace(scenario, route=None)
    motion = ego_motion(scenario)
    rules = MapRules(site.intersection_map)
    bicycle_wheelbase = 0.6 * 4.97
    for frame in range(scenario.num_frames):
        wheels = wheel_points(
            np.array([motion.x_m[frame], motion.y_m[frame]]), motion.yaw_rad[frame],
            bicycle_wheelbase, 2.0,
        )  # fmt: skip
        assert not rules.wheels_off_road(wheels), frame
    assert check_clip(scenario, site.intersection_map, rules) == ()


@pytest.mark.slow
def test_split_leaves_flagged_clips_out_unless_kept(
    synthetic_root: Path, tmp_path: Path, capsys
) -> None:
    # the first clips of a seed's set are the same files whatever the set's size: these are
    # `synth --clips 4 --seed 0`
    root = copy_clips(synthetic_root, tmp_path / "data", store.scenario_ids(synthetic_root)[:4])
    assert main(["curate", str(root), "--workers", "1"]) == 0
    assert "expert replay: 4 of 4 clips driven cleanly, 0 flagged" in capsys.readouterr().out
    flagged = store.scenario_ids(root)[1]
    store.write_metadata_entry(
        root, flagged, METADATA_KEY, record((Flag("log replay", "red_light", 3),))
    )
    assert main(["split", str(root)]) == 0
    assert "1 clips left out (1 flagged by the expert-replay check)" in capsys.readouterr().out
    kept = splits.scenario_ids(splits.split_path(root, "default"), "all")
    assert flagged not in kept and len(kept) == 3
    assert main(["split", str(root), "--keep-flagged", "--name", "all"]) == 0
    assert flagged in splits.scenario_ids(splits.split_path(root, "all"), "all")


@pytest.mark.slow
def test_curate_checks_again_what_it_curated_and_a_rerun_resumes(
    synthetic_root: Path, tmp_path: Path, capsys
) -> None:
    root = copy_clips(synthetic_root, tmp_path / "data", store.scenario_ids(synthetic_root)[:2])
    assert main(["curate", str(root), "--workers", "2"]) == 0
    first = store.scenario_ids(root)[0]
    assert recorded_flags(store.read_meta(root, first)["metadata"]) == ()
    meta_file = store.scenario_dir(root, first) / "meta.json"
    stamp = meta_file.stat().st_mtime_ns
    capsys.readouterr()
    assert main(["curate", str(root), "--check-only"]) == 0  # nothing left to check
    assert meta_file.stat().st_mtime_ns == stamp
    assert "2 of 2 clips driven cleanly" in capsys.readouterr().out
