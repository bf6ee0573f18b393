"""Annotations: visibility from the camera mask, points in boxes."""

import numpy as np
import pytest
from factories import small_map, small_scenario, straight_track

from drivee2e_data.hdmap import Building
from drivee2e_data.scenario import AgentClass
from drivee2e_data.sensors.annotate import (
    box_corners_3d,
    points_in_box,
    projected_area,
    visibility_level,
    visible_share,
)
from drivee2e_data.sensors.camera import encode_jpeg, render
from drivee2e_data.sensors.rig import default_rig, pose
from drivee2e_data.sim.world import World

FRAMES = 5


def _parked(track_id: str, x_m: float) -> object:
    return straight_track(
        track_id, FRAMES, AgentClass.CAR, x_m=np.full(FRAMES, x_m), vx_mps=np.zeros(FRAMES)
    )


def _scene(with_building: bool):
    building = Building(
        "wall", np.array([[14.0, -4.0], [16.0, -4.0], [16.0, 4.0], [14.0, 4.0]]), 8.0
    )
    intersection_map = small_map(buildings=(building,) if with_building else ())
    scenario = small_scenario(
        FRAMES, tracks=(_parked("ego", 5.0), _parked("hidden", 25.0)), ego_id="ego"
    )
    return intersection_map, scenario


def _front_view(intersection_map, scenario):
    world = World(intersection_map, scenario, renderer="tiny")
    world.place_ego(5.0, 0.0, "ego")
    world.set_time(0)
    ego_to_world = pose(np.eye(3), np.array([5.0 - 1.4, 0.0, 0.0]))
    frame = render(world, default_rig().camera("CAM_FRONT"), ego_to_world)
    return world, frame, ego_to_world


@pytest.mark.parametrize("with_building", [True, False])
def test_a_box_behind_a_building_is_not_visible(with_building):
    intersection_map, scenario = _scene(with_building)
    world, frame, ego_to_world = _front_view(intersection_map, scenario)
    try:
        track = scenario.track("hidden")
        corners = box_corners_3d(track, 0, world.blueprints["hidden"].size_m)
        share = visible_share(frame, world.bodies["hidden"], corners, ego_to_world)
        assert not projected_area(
            frame, corners, ego_to_world
        ).is_empty  # it is in the image's view
        if with_building:
            assert share == 0.0 and visibility_level(share) == 0
        else:
            assert share > 0.8 and visibility_level(share) == 4
            area = projected_area(frame, corners, ego_to_world)
            assert (frame.mask == world.bodies["hidden"]).sum() > 0.8 * area.area
    finally:
        world.close()


def test_visibility_levels_follow_nuscenes_bins():
    assert [visibility_level(v) for v in (0.0, 0.2, 0.4, 0.5, 0.7, 0.95)] == [0, 1, 2, 2, 3, 4]


def test_points_in_a_rotated_box():
    track = straight_track(
        "a", 1, yaw_rad=np.array([np.pi / 4]), x_m=np.array([10.0]), y_m=np.array([5.0])
    )
    corners = box_corners_3d(track, 0)
    inside = np.array(
        [[10.0, 5.0, 0.75], [10.0 + 1.5, 5.0 + 1.5, 0.5]]
    )  # centre; 2.1 m along the heading
    outside = np.array(
        [[10.0 + 1.5, 5.0 - 1.5, 0.5], [10.0, 5.0, 2.0]]
    )  # 2.1 m sideways; above the roof
    assert points_in_box(np.concatenate([inside, outside]), corners) == 2


def test_jpeg_round_trip_is_close():
    import cv2

    rgb = np.zeros((90, 160, 3), np.uint8)
    rgb[:, :80] = (200, 40, 40)
    decoded = cv2.imdecode(np.frombuffer(encode_jpeg(rgb, 95), np.uint8), cv2.IMREAD_COLOR)[
        :, :, ::-1
    ]
    assert np.abs(decoded.astype(int) - rgb).mean() < 3
