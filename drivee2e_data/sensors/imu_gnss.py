"""GNSS and IMU from the ego's motion: local ENU <-> WGS84 through the map's origin (exact
ellipsoidal conversion via ECEF, with pyproj for geodetic <-> ECEF), and the IMU's acceleration
and angular velocity from the ego's track.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from pyproj import Transformer

from drivee2e_data.hdmap import GeoOrigin
from drivee2e_data.scenario import FRAME_PERIOD_NS, Track

_TO_ECEF = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
_FROM_ECEF = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)


def _enu_rotation(origin: GeoOrigin) -> NDArray[np.float64]:
    """Rows: east, north, up unit vectors in ECEF at the origin."""
    lat, lon = np.deg2rad(origin.latitude_deg), np.deg2rad(origin.longitude_deg)
    return np.array(
        [
            [-np.sin(lon), np.cos(lon), 0.0],
            [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)],
            [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)],
        ]
    )


def _origin_ecef(origin: GeoOrigin) -> NDArray[np.float64]:
    return np.array(
        _TO_ECEF.transform(origin.longitude_deg, origin.latitude_deg, origin.altitude_m)
    )


def enu_to_wgs84(points_enu_m: NDArray[np.float64], origin: GeoOrigin) -> NDArray[np.float64]:
    """(N, 3) local ENU points (metres) to (N, 3) latitude, longitude (degrees), altitude (m)."""
    points = np.atleast_2d(points_enu_m).astype(np.float64)
    ecef = points @ _enu_rotation(origin) + _origin_ecef(origin)
    lon, lat, alt = _FROM_ECEF.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2])
    return np.stack([lat, lon, alt], axis=-1)


def wgs84_to_enu(
    latitude_longitude_altitude: NDArray[np.float64], origin: GeoOrigin
) -> NDArray[np.float64]:
    """Inverse of `enu_to_wgs84`."""
    values = np.atleast_2d(latitude_longitude_altitude).astype(np.float64)
    x, y, z = _TO_ECEF.transform(values[:, 1], values[:, 0], values[:, 2])
    return (np.stack([x, y, z], axis=-1) - _origin_ecef(origin)) @ _enu_rotation(origin).T


def imu(track: Track) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per frame, acceleration `(T, 3)` in the vehicle frame (x forward, y left, z up, gravity
    included as +9.81 m/s^2 on z, as an accelerometer reads it) and angular velocity `(T, 3)`
    (rad/s, yaw rate on z), from central differences of the track's velocity and heading."""
    dt = FRAME_PERIOD_NS / 1e9
    velocity = np.stack([track.vx_mps, track.vy_mps], -1)
    accel_world = np.gradient(velocity, dt, axis=0)
    yaw = np.unwrap(np.nan_to_num(track.yaw_rad))
    c, s = np.cos(yaw), np.sin(yaw)
    forward = accel_world[:, 0] * c + accel_world[:, 1] * s
    left = -accel_world[:, 0] * s + accel_world[:, 1] * c
    acceleration = np.stack([forward, left, np.full(len(yaw), 9.81)], -1)
    angular = np.stack([np.zeros(len(yaw)), np.zeros(len(yaw)), np.gradient(yaw, dt)], -1)
    return acceleration, angular
