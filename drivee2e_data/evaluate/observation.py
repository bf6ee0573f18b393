"""Sensor observations in closed loop: the agent's cameras and LiDAR rendered from the ego's
actual pose by the collection's own code (same rig, weather and light, JPEG quality), with the
scene posed at the step."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.evaluate.agent import LIDAR
from drivee2e_data.evaluate.traffic import AgentPose
from drivee2e_data.scenario import SignalState
from drivee2e_data.sensors import lidar
from drivee2e_data.sensors.camera import NO_DEPTH, encode_jpeg, render, with_conditions
from drivee2e_data.sensors.ego_state import se3
from drivee2e_data.sensors.suite import SuiteOptions, configured_rig
from drivee2e_data.sim.vehicle import VehicleState
from drivee2e_data.sim.world import World

JPEG_QUALITY = 85  # as collection's default


class SensorObserver:
    """Renders the sensors in `sensors` (camera names, `LIDAR_TOP`) of the default rig at
    `image_size` (width, height; None for 1600x900)."""

    def __init__(
        self, world: World, sensors: tuple[str, ...], image_size: tuple[int, int] | None
    ) -> None:
        cameras = tuple(name for name in sensors if name != LIDAR)
        self.world, self.with_lidar = world, LIDAR in sensors
        self.rig = configured_rig(SuiteOptions(cameras=cameras, image_size=image_size))

    def observe(
        self,
        step: int,
        frame: int,
        state: VehicleState,
        ground_z_m: float,
        poses: list[AgentPose],
        signals: dict[str, SignalState],
    ) -> tuple[dict[str, bytes], NDArray[np.float32] | None]:
        """JPEG per camera and the LiDAR points `(N, 5)` at this step; weather noise is seeded
        by the log frame `frame` as in collection."""
        world = self.world
        world.place_ego(state.x_m, state.y_m, world.ego_id, state.yaw_rad)  # its headlights
        world.show({p.track_id: (p.x_m, p.y_m, p.z_m, p.yaw_rad) for p in poses}, signals, frame)
        ego_to_world = se3(state.x_m, state.y_m, ground_z_m, state.yaw_rad)
        images = {}
        for camera in self.rig.cameras:
            view = render(world, camera, ego_to_world, mask=False, depth_at=NO_DEPTH)
            images[camera.name] = encode_jpeg(with_conditions(world, view, frame), JPEG_QUALITY)
        points = None
        if self.with_lidar:
            sweep = lidar.sweep(
                world.client,
                self.rig.lidar,
                ego_to_world @ self.rig.lidar.sensor_to_ego,
                world.twin.segmentation,
                world.twin.paint_raster(),
            )
            points = np.column_stack(
                [sweep.points_m, sweep.intensity, sweep.ring.astype(np.float32)]
            ).astype(np.float32)
        return images, points
