"""The ego's sensor rig (SPEC.md): six cameras, a 64-channel LiDAR, five radars, IMU and GNSS,
with nuScenes-like mounts. Pure data and frame algebra; no simulator.

Frames (nuScenes): ego x forward, y left, z up, origin at the rear axle on the ground; camera
x right, y down, z forward. Poses are 4x4 sensor-to-ego transforms.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

IMAGE_WIDTH, IMAGE_HEIGHT = 1600, 900
# Camera to ego rotation for a camera looking along ego +x: its z (forward) is ego x, its x
# (right) is ego -y, its y (down) is ego -z.
_LOOK_FORWARD = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _yaw(angle_rad: float) -> NDArray[np.float64]:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose(rotation: NDArray[np.float64], translation_m: NDArray[np.float64]) -> NDArray[np.float64]:
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = rotation, translation_m
    return matrix


@dataclass(frozen=True)
class Camera:
    name: str
    sensor_to_ego: NDArray[np.float64]  # (4, 4)
    horizontal_fov_deg: float
    width: int = IMAGE_WIDTH
    height: int = IMAGE_HEIGHT

    @property
    def intrinsic(self) -> NDArray[np.float64]:
        """(3, 3) pinhole matrix K: square pixels, principal point at the image centre."""
        focal = 0.5 * self.width / np.tan(np.deg2rad(self.horizontal_fov_deg) / 2)
        return np.array(
            [[focal, 0.0, self.width / 2], [0.0, focal, self.height / 2], [0.0, 0.0, 1.0]]
        )

    @property
    def vertical_fov_deg(self) -> float:
        focal = self.intrinsic[0, 0]
        return float(np.rad2deg(2 * np.arctan(0.5 * self.height / focal)))

    def project(
        self, points_ego_m: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """Pixel coordinates `(N, 2)` of ego-frame points `(N, 3)`, and which lie in front."""
        ego_to_camera = np.linalg.inv(self.sensor_to_ego)
        homogeneous = np.column_stack([points_ego_m, np.ones(len(points_ego_m))])
        camera = (ego_to_camera @ homogeneous.T).T[:, :3]
        in_front = camera[:, 2] > 1e-6
        pixels = (self.intrinsic @ camera.T).T
        return pixels[:, :2] / np.where(in_front, pixels[:, 2], 1.0)[:, None], in_front


@dataclass(frozen=True)
class Lidar:
    name: str
    sensor_to_ego: NDArray[np.float64]
    channels: int = 64
    range_m: float = 85.0
    upper_deg: float = 10.0
    lower_deg: float = -30.0
    azimuth_step_deg: float = 0.2

    @property
    def elevations_rad(self) -> NDArray[np.float64]:
        """(channels,) beam elevations, ring 0 the highest."""
        return np.deg2rad(np.linspace(self.upper_deg, self.lower_deg, self.channels))

    @property
    def azimuths_rad(self) -> NDArray[np.float64]:
        return np.deg2rad(np.arange(0.0, 360.0, self.azimuth_step_deg))


@dataclass(frozen=True)
class Radar:
    name: str
    sensor_to_ego: NDArray[np.float64]
    range_m: float = 100.0
    horizontal_fov_deg: float = 90.0


@dataclass(frozen=True)
class Rig:
    cameras: tuple[Camera, ...]
    lidar: Lidar
    radars: tuple[Radar, ...]

    def camera(self, name: str) -> Camera:
        return next(c for c in self.cameras if c.name == name)


# name, yaw (deg, CCW from ego +x), mount (x, y, z) in metres, horizontal FOV (deg)
CAMERA_MOUNTS = (
    ("CAM_FRONT", 0.0, (1.70, 0.0, 1.55), 70.0),
    ("CAM_FRONT_RIGHT", -55.0, (1.55, -0.50, 1.55), 70.0),
    ("CAM_FRONT_LEFT", 55.0, (1.55, 0.50, 1.55), 70.0),
    ("CAM_BACK", 180.0, (0.0, 0.0, 1.55), 110.0),
    ("CAM_BACK_LEFT", 110.0, (1.05, 0.50, 1.55), 70.0),
    ("CAM_BACK_RIGHT", -110.0, (1.05, -0.50, 1.55), 70.0),
)
RADAR_MOUNTS = (
    ("RADAR_FRONT", 0.0, (3.40, 0.0, 0.50)),
    ("RADAR_FRONT_LEFT", 80.0, (3.00, 0.70, 0.50)),
    ("RADAR_FRONT_RIGHT", -80.0, (3.00, -0.70, 0.50)),
    ("RADAR_BACK_LEFT", 170.0, (-0.60, 0.70, 0.50)),
    ("RADAR_BACK_RIGHT", -170.0, (-0.60, -0.70, 0.50)),
)
LIDAR_MOUNT_M = (0.95, 0.0, 1.85)


def default_rig() -> Rig:
    """The nuScenes-like rig of SPEC.md."""
    cameras = tuple(
        Camera(name, pose(_yaw(np.deg2rad(yaw)) @ _LOOK_FORWARD, np.array(mount)), fov)
        for name, yaw, mount, fov in CAMERA_MOUNTS
    )
    radars = tuple(
        Radar(name, pose(_yaw(np.deg2rad(yaw)), np.array(mount)))
        for name, yaw, mount in RADAR_MOUNTS
    )
    return Rig(cameras, Lidar("LIDAR_TOP", pose(np.eye(3), np.array(LIDAR_MOUNT_M))), radars)
