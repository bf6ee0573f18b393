import numpy as np
import pytest
from factories import straight_track

from drivee2e_data.hdmap import GeoOrigin
from drivee2e_data.sensors.imu_gnss import enu_to_wgs84, imu, wgs84_to_enu

ORIGIN = GeoOrigin(39.75, 116.5, 40.0)


def test_gnss_round_trip_within_1cm():
    rng = np.random.default_rng(0)
    points = rng.uniform(-500, 500, size=(200, 3)) * [1, 1, 0.02]
    back = wgs84_to_enu(enu_to_wgs84(points, ORIGIN), ORIGIN)
    assert np.abs(back - points).max() < 0.01


def test_a_kilometre_north_is_about_0_009_degrees():
    lat, lon, alt = enu_to_wgs84(np.array([[0.0, 1000.0, 0.0]]), ORIGIN)[0]
    assert lat - ORIGIN.latitude_deg == pytest.approx(
        1000 / 111_030, rel=2e-3
    )  # metres per degree at 39.75 N
    assert lon == pytest.approx(ORIGIN.longitude_deg, abs=1e-9)
    assert alt == pytest.approx(
        40.0 + 1000**2 / (2 * 6_371_000), abs=0.05
    )  # the plane rises off the ellipsoid


def test_imu_of_a_braking_car_and_a_circle():
    speed = 10.0 - 2.0 * np.arange(20) * 0.1  # braking at 2 m/s^2
    braking = straight_track("b", 20, vx_mps=speed, x_m=np.cumsum(speed) * 0.1)
    acceleration, angular = imu(braking)
    assert np.allclose(acceleration[:, 0], -2.0) and np.allclose(acceleration[:, 2], 9.81)
    t = np.arange(40) * 0.1
    yaw = 0.5 * t  # 0.5 rad/s at 5 m/s: a 10 m circle
    circle = straight_track("c", 40, x_m=10 * np.sin(yaw), y_m=10 * (1 - np.cos(yaw)), yaw_rad=yaw,
                            vx_mps=5 * np.cos(yaw), vy_mps=5 * np.sin(yaw))  # fmt: skip
    acceleration, angular = imu(circle)
    assert np.allclose(angular[:, 2], 0.5)
    assert np.allclose(acceleration[1:-1, 1], 2.5, atol=0.02)  # v^2 / r towards the centre (left)
