import numpy as np

from drivee2e_data import geometry


def test_wrap_angle_maps_into_half_open_interval():
    wrapped = geometry.wrap_angle(np.array([np.pi, -np.pi, 3 * np.pi / 2, 0.25]))
    assert np.allclose(wrapped, [-np.pi, -np.pi, -np.pi / 2, 0.25])


def test_frames_round_trip():
    points = np.array([[1.0, 2.0], [-3.0, 0.5]])
    local = geometry.to_local_frame(points, np.array([1.0, 1.0]), np.pi / 2)
    assert np.allclose(
        local[0], [1.0, 0.0]
    )  # 1 m north of the origin is 1 m ahead when facing north
    back = geometry.to_world_frame(local, np.array([1.0, 1.0]), np.pi / 2)
    assert np.allclose(back, points)


def test_quaternion_yaw_round_trip_and_rotation():
    yaw = np.array([0.0, 0.3, -2.0, 3.1])
    quaternion = geometry.quaternion_from_yaw(yaw)
    assert np.allclose(geometry.yaw_from_quaternion(quaternion), yaw)
    rotation = geometry.rotation_from_quaternion(geometry.quaternion_from_yaw(np.pi / 2))
    assert np.allclose(rotation @ np.array([1.0, 0.0, 0.0]), [0.0, 1.0, 0.0])


def test_interpolate_polyline_gives_positions_and_segment_headings():
    points = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    s = geometry.polyline_arclength(points)
    assert np.allclose(s, [0.0, 10.0, 20.0])
    xy, heading = geometry.interpolate_polyline(points, s, np.array([5.0, 15.0, 99.0]))
    assert np.allclose(xy, [[5.0, 0.0], [10.0, 5.0], [10.0, 10.0]])
    assert np.allclose(heading, [0.0, np.pi / 2, np.pi / 2])


def test_resample_keeps_ends_and_spacing():
    points = np.array([[0.0, 0.0], [0.0, 7.0]])
    resampled = geometry.resample_polyline(points, 2.0)
    assert np.allclose(resampled[[0, -1]], points)
    assert np.allclose(np.diff(resampled[:, 1]), 7.0 / (len(resampled) - 1))


def test_box_corners_and_overlap():
    corners = geometry.box_corners_2d(np.array([0.0, 0.0]), 0.0, 4.0, 2.0)
    assert np.allclose(corners, [[2, 1], [-2, 1], [-2, -1], [2, -1]])
    a = geometry.box_corners_2d(np.array([0.0, 0.0]), 0.0, 4.0, 2.0)
    touching = geometry.box_corners_2d(np.array([4.0, 0.0]), 0.0, 4.0, 2.0)
    overlapping = geometry.box_corners_2d(np.array([3.9, 0.0]), 0.0, 4.0, 2.0)
    # a rotated box whose axis-aligned bounds overlap a's, while the box itself does not
    diagonal = geometry.box_corners_2d(np.array([2.75, 0.75]), -np.pi / 4, 4.0, 0.5)
    assert not geometry.boxes_overlap(a, touching)
    assert geometry.boxes_overlap(a, overlapping)
    assert not geometry.boxes_overlap(a, diagonal)
    stacked = geometry.boxes_overlap(np.stack([a, a]), np.stack([touching, overlapping]))
    assert stacked.tolist() == [False, True]


def test_curvature_of_a_circle():
    angle = np.linspace(0, np.pi, 400)
    circle = 7.0 * np.stack([np.cos(angle), np.sin(angle)], axis=-1)
    assert np.allclose(geometry.polyline_curvature(circle)[5:-5], 1 / 7.0, rtol=1e-3)
