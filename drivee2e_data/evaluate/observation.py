"""Sensor observations in closed loop: the agent's cameras and LiDAR rendered from the ego's
actual pose by the collection's own code (same rig, weather and light), with the scene posed at
the step.

Two ways to the images, chosen by what the agent declares:
- `image_size` alone: JPEG bytes per camera at that size, the collection's own path (the same
  bytes as the log where the pose is the logged one).
- `input_size` too (the size the agent's network reads, as the Dataset decodes the logged JPEG
  to it): each camera is drawn at the largest JPEG reduction of `image_size` (1/2, 1/4 or 1/8,
  one that divides it) that keeps at least `SUPERSAMPLE` times `input_size`, area-resized to
  `input_size` on the GPU (only the input's pixels are read back) and exposed as metered
  there, its noise and rain made at the full size and averaged
  (`sensors.camera.render_reduced`): planar RGB `(3, H, W)` uint8, no JPEG either way, at a
  fraction of the pixels.
  The logged image is drawn at the full size and averaged down (by the JPEG's DCT reduction
  and the Dataset's area resize), so a lane line thinner than a pixel of the input shows as a
  faint continuous line; drawn at the input size itself it would break into dashes where it
  crosses pixel centres: twice the input's resolution, averaged, is what keeps them alike.
  Measured against the logged images (docs/closedloop.md): PSNR above `PARITY_PSNR_DB` on
  every weather and time of day (tested).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from drivee2e_data.evaluate.agent import LIDAR
from drivee2e_data.evaluate.traffic import AgentPose, Traffic
from drivee2e_data.loaders.images import reduction
from drivee2e_data.scenario import Scenario, SignalState
from drivee2e_data.sensors import lidar
from drivee2e_data.sensors.camera import (
    NO_DEPTH,
    encode_jpeg,
    render,
    render_reduced,
    with_conditions,
)
from drivee2e_data.sensors.ego_state import ego_motion, se3
from drivee2e_data.sensors.rig import IMAGE_HEIGHT, IMAGE_WIDTH
from drivee2e_data.sensors.suite import SuiteOptions, configured_rig
from drivee2e_data.sim.gl_readback import bgra_under
from drivee2e_data.sim.vehicle import VehicleState
from drivee2e_data.sim.world import World

JPEG_QUALITY = 85  # as collection's default
# the cheap path's images against the logged ones decoded as the Dataset decodes them, per
# camera image (docs/closedloop.md has the measured spread)
PARITY_PSNR_DB = 28.0
# drawn at no less than this many times the input's width and height before the area resize
SUPERSAMPLE = 2


class SensorObserver:
    """Renders the sensors in `sensors` (camera names, `LIDAR_TOP`) of the default rig for an
    agent whose training images were collected at `image_size` (width, height; None for
    1600x900); with `input_size`, drawn small (at least `supersample` times `input_size`),
    area-resized to it by the renderer, exposed, and served as the decoded pixels at that size
    (`Observation.pixels`) instead of JPEG bytes (`Observation.images`)."""

    def __init__(
        self,
        world: World,
        sensors: tuple[str, ...],
        image_size: tuple[int, int] | None,
        input_size: tuple[int, int] | None = None,
        supersample: int = SUPERSAMPLE,
    ) -> None:
        cameras = tuple(name for name in sensors if name != LIDAR)
        self.world, self.with_lidar = world, LIDAR in sensors
        self.full_size = tuple(image_size or (IMAGE_WIDTH, IMAGE_HEIGHT))
        self.input_size = None if input_size is None else tuple(input_size)
        drawn = self.full_size
        if world.renderer != "gl":  # pybullet's renderers draw no weather: the JPEG path
            self.input_size = None
        if self.input_size is not None:
            wanted = (supersample * self.input_size[0], supersample * self.input_size[1])
            factor = reduction(self.full_size, wanted)
            drawn = (self.full_size[0] // factor, self.full_size[1] // factor)
        self.rig = configured_rig(SuiteOptions(cameras=cameras, image_size=self.full_size))
        self.drawn_rig = configured_rig(SuiteOptions(cameras=cameras, image_size=drawn))

    def observe(
        self,
        step: int,
        frame: int,
        state: VehicleState,
        ground_z_m: float,
        poses: list[AgentPose],
        signals: dict[str, SignalState],
        centre_xy_m: NDArray[np.float64] | None = None,
        shown: bool = False,
    ) -> tuple[dict[str, bytes | NDArray[np.uint8]], NDArray[np.float32] | None]:
        """Per camera its JPEG (or, with `input_size`, its decoded pixels `(3, H, W)`), and the
        LiDAR points `(N, 5)` at this step; weather noise is seeded by the log frame `frame` as
        in collection. `centre_xy_m`: the ego's box centre (the state holds its rear axle),
        where its headlights and its shadow are placed, as collection places them. `shown`:
        `poses` and `signals` were already shown (`show`), only the ego is placed."""
        world = self.world
        centre = state.xy_m if centre_xy_m is None else np.asarray(centre_xy_m, np.float64)
        world.place_ego(float(centre[0]), float(centre[1]), world.ego_id, state.yaw_rad)
        if not shown:
            self.show(frame, poses, signals, sync=False)
        ego_to_world = se3(state.x_m, state.y_m, ground_z_m, state.yaw_rad)
        images: dict[str, bytes | NDArray[np.uint8]] = {}
        if self.input_size is None:
            for camera in self.drawn_rig.cameras:
                view = render(world, camera, ego_to_world, mask=False, depth_at=NO_DEPTH)
                images[camera.name] = encode_jpeg(with_conditions(world, view, frame), JPEG_QUALITY)
        elif self.drawn_rig.cameras:
            reduced = render_reduced(world, self.drawn_rig.cameras, ego_to_world, self.input_size,
                                     frame, self.full_size)  # fmt: skip
            images = {name: planar(rgb, self.input_size) for name, rgb in reduced.items()}
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

    def show(
        self,
        frame: int,
        poses: list[AgentPose],
        signals: dict[str, SignalState],
        sync: bool = True,
    ) -> None:
        """The agents at `poses` and the signals at `signals` in the world, their models moving
        as at the log's `frame`; with `sync`, handed to the renderer at once
        (`World.sync_bodies`): a scene shown ahead of its step, the ego placed at the step."""
        placements = {p.track_id: (p.x_m, p.y_m, p.z_m, p.yaw_rad) for p in poses}
        self.world.show(placements, signals, frame)
        if sync:
            self.world.sync_bodies()


class LoggedDrive:
    """A clip's ego as logged, for the observer: at a frame, its logged pose and speed, the
    other agents where the log and `Traffic` place them around it, the signals' logged states.
    What the parity checks and profiles drive the observer with (the closed loop's own ego is
    the simulated one, `evaluate/episode.py`)."""

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        self.motion, self.traffic = ego_motion(scenario), Traffic(scenario)

    def observe(
        self, observer: SensorObserver, frame: int
    ) -> tuple[dict[str, bytes | NDArray[np.uint8]], NDArray[np.float32] | None]:
        """`observer.observe` at the logged frame `frame` (its noise seeded by that frame)."""
        motion, ego = self.motion, self.scenario.ego
        state = VehicleState(float(motion.x_m[frame]), float(motion.y_m[frame]),
                             float(motion.yaw_rad[frame]), float(motion.speed_mps[frame]))  # fmt: skip
        centre = np.array([ego.x_m[frame], ego.y_m[frame]])
        poses = self.traffic.poses(frame, centre, state.yaw_rad, state.speed_mps,
                                   tuple(motion.size_m[:2]))  # fmt: skip
        signals = {signal.signal_id: signal.state_at(frame) for signal in self.scenario.signals}
        z = float(motion.z_m[frame])
        return observer.observe(frame, frame, state, z, poses, signals, centre)


def planar(rgb: NDArray[np.uint8], size: tuple[int, int]) -> NDArray[np.uint8]:
    """An RGB image `(h, w, 3)` area-resized to `size` (width, height) as planar RGB
    `(3, H, W)`, as the Dataset's decoder lays its images out. A view of the GL renderer's
    BGRA read is resized as it lies (channels are resized one by one, so the bytes are the
    same) and split into planes by OpenCV: numpy's copy of such a view, a pixel at a time, had
    been half of this function's time (2.5 against 1.3 ms a 533x300 view, one thread)."""
    bgra = bgra_under(rgb)
    if bgra is None:
        rgb = np.ascontiguousarray(rgb)
        if rgb.shape[1::-1] != tuple(size):
            rgb = cv2.resize(rgb, tuple(size), interpolation=cv2.INTER_AREA)
        return np.ascontiguousarray(np.moveaxis(rgb, -1, 0))
    if bgra.shape[1::-1] != tuple(size):
        bgra = cv2.resize(bgra, tuple(size), interpolation=cv2.INTER_AREA)
    blue, green, red, _ = cv2.split(bgra)
    return np.stack([red, green, blue])
