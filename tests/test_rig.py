"""The sensor rig's calibrations: known answers from frame algebra."""

import numpy as np
import pytest

from drivee2e_data.sensors.rig import IMAGE_HEIGHT, IMAGE_WIDTH, default_rig


def test_a_point_straight_ahead_lands_in_the_front_image_centre():
    front = default_rig().camera("CAM_FRONT")
    pixels, in_front = front.project(np.array([[21.70, 0.0, 1.55]]))  # 20 m ahead of the lens
    assert in_front[0] and np.allclose(pixels[0], [IMAGE_WIDTH / 2, IMAGE_HEIGHT / 2])


def test_left_is_left_and_up_is_up_in_the_image():
    front = default_rig().camera("CAM_FRONT")
    pixels, _ = front.project(np.array([[21.70, 2.0, 1.55], [21.70, 0.0, 3.55]]))
    assert pixels[0, 0] < IMAGE_WIDTH / 2  # a point to the ego's left is left of centre
    assert pixels[1, 1] < IMAGE_HEIGHT / 2  # a point above is above the centre


def test_front_camera_field_of_view_is_70_degrees():
    front = default_rig().camera("CAM_FRONT")
    edge = 20.0 * np.tan(np.deg2rad(35.0))
    pixels, _ = front.project(np.array([[21.70, -edge, 1.55]]))  # 35 deg to the right
    assert pixels[0, 0] == pytest.approx(IMAGE_WIDTH, abs=1e-6)
    assert front.vertical_fov_deg == pytest.approx(
        2 * np.rad2deg(np.arctan(450 / front.intrinsic[0, 0]))
    )


def test_cameras_cover_the_whole_circle():
    rig = default_rig()
    covered = np.zeros(360, bool)
    for camera in rig.cameras:
        forward = camera.sensor_to_ego[:3, 2]
        yaw = np.rad2deg(np.arctan2(forward[1], forward[0]))
        half = camera.horizontal_fov_deg / 2
        for angle in np.arange(np.floor(yaw - half), np.ceil(yaw + half)):
            covered[int(angle) % 360] = True
    assert covered.all() and len(rig.cameras) == 6


def test_lidar_and_radars_match_the_spec():
    rig = default_rig()
    assert rig.lidar.channels == 64 and rig.lidar.range_m == 85.0
    assert np.rad2deg(rig.lidar.elevations_rad[[0, -1]]).tolist() == pytest.approx([10.0, -30.0])
    assert len(rig.lidar.azimuths_rad) == 1800  # 0.2 degree steps
    assert [r.name for r in rig.radars] == [
        "RADAR_FRONT", "RADAR_FRONT_LEFT", "RADAR_FRONT_RIGHT", "RADAR_BACK_LEFT", "RADAR_BACK_RIGHT"
    ]  # fmt: skip
    assert all(r.range_m == 100.0 for r in rig.radars)
