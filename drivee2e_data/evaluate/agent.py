"""What a driving model sees and returns in closed loop: the `Agent` protocol, the route it is
given, its observations and its actions.

Frames and units: world = the map's local ENU (metres, radians); ego = the nuScenes ego frame at
the rear axle (x forward, y left); waypoints at 2 Hz (0.5 s apart) in the ego frame of the step.
Images are JPEG bytes as in the logs (the same encoder and quality as collection), so a model
sees in closed loop what it was trained on.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.errors import DriveE2EError
from drivee2e_data.sensors.rig import Rig
from drivee2e_data.sim.vehicle import Control

LIDAR = "LIDAR_TOP"


class AgentFailure(DriveE2EError):
    """The agent crashed, hung or answered something that is not an action: the episode ends
    with this reason, the evaluation goes on."""


@dataclass(frozen=True)
class Waypoints:
    """Planned ego positions `(N, 2)` at 2 Hz in the ego frame of the step (first one 0.5 s
    ahead); the harness's PID controllers turn them into controls."""

    xy_m: NDArray[np.float64]


@dataclass(frozen=True)
class Route:
    """The ego's route: down-sampled waypoints `(W, 2)` in the world with a high-level command
    each (1 right, 2 left, 3 straight: what the command will be when the ego reaches them),
    their WGS84 latitude, longitude, altitude `(W, 3)`, and the logged driver's path with its
    times `(T, 3)` (t_s, x_m, y_m; privileged: for the log-replay expert, a fair model ignores
    it)."""

    scenario_id: str
    waypoints_xy_m: NDArray[np.float64]
    commands: NDArray[np.int64]
    waypoints_lat_lon_alt: NDArray[np.float64]
    logged_path_txy: NDArray[np.float64]
    category: str = ""


@dataclass(frozen=True)
class Observation:
    """One 10 Hz step of what the agent asked for, rendered from the ego's actual pose.

    Always present: time, pose (GNSS in the map frame and as WGS84, compass), speed, IMU, the
    ego status and 2 Hz history as the Dataset serves them (`ego_status` (10,), history `(4,
    2)` oldest first in the ego frame with its mask), the command, and the target point: the
    next route waypoint at least 10 m ahead, in the ego frame. `images` (JPEG) and
    `lidar_points` (N, 5: x, y, z, intensity, ring in the LiDAR frame) only for the sensors
    the agent lists."""

    step: int
    t_s: float
    xy_m: NDArray[np.float64]
    yaw_rad: float
    lat_lon_alt: NDArray[np.float64]
    speed_mps: float
    imu_acceleration_mps2: NDArray[np.float64]
    imu_angular_velocity_radps: NDArray[np.float64]
    ego_status: NDArray[np.float64]
    history_xy_m: NDArray[np.float64]
    history_mask: NDArray[np.bool_]
    command: int
    target_point_m: NDArray[np.float64]
    images: dict[str, bytes] = field(default_factory=dict)
    lidar_points: NDArray[np.float32] | None = None
    # for an agent that declares `input_size`: each camera's decoded image `(3, H, W)` uint8 at
    # that size, instead of `images` (evaluate/observation.py)
    pixels: dict[str, NDArray[np.uint8]] = field(default_factory=dict)

    def image(
        self, camera: str, reduction: int = 1, size: tuple[int, int] | None = None
    ) -> NDArray[np.uint8]:
        """The camera's image decoded to RGB `(H, W, 3)`: with `size` (width, height) as the
        Dataset decodes it to that size, the area reduction of the image (the pixels a model
        trained on `DriveE2EDataset(..., image_size=size)` read); else at 1/`reduction` size
        (1, 2, 4, 8; a reduction that does not divide the size ends in a partial block of
        padding: 1600x900 at 1/8 is 113 rows for 112.5)."""
        import cv2

        if size is not None:
            from drivee2e_data.loaders.images import decode_cpu, jpeg_size

            jpeg = self.images[camera]
            return np.ascontiguousarray(np.moveaxis(decode_cpu(jpeg, jpeg_size(jpeg), size), 0, -1))
        flags = {1: cv2.IMREAD_COLOR, 2: cv2.IMREAD_REDUCED_COLOR_2,
                 4: cv2.IMREAD_REDUCED_COLOR_4, 8: cv2.IMREAD_REDUCED_COLOR_8}[reduction]  # fmt: skip
        bgr = cv2.imdecode(np.frombuffer(self.images[camera], np.uint8), flags)
        return np.ascontiguousarray(bgr[:, :, ::-1])


@runtime_checkable
class Agent(Protocol):
    """A driving model. `sensors` lists the cameras (rig names) and `LIDAR_TOP` it wants
    rendered each step; `image_size` (width, height) or None for the rig's 1600x900: the size
    its training images were collected at. An agent may also declare `input_size` (width,
    height), the size its network reads images at: it then gets `Observation.pixels`, drawn
    at a fraction of `image_size` and decoded as the Dataset decodes, instead of JPEG bytes.
    An agent answered by another process may offer `act_later(observation)`, which sends the
    observation and returns a function that waits for the action: the episode then does its
    own work of the step (the rules at the step driven, the next step's scene where the
    traffic ignores the ego) while the agent thinks, with the same result
    (`evaluate/episode.py`; the policy server's `ServedAgent` offers it)."""

    name: str
    sensors: tuple[str, ...]
    image_size: tuple[int, int] | None

    def setup(self, route: Route, rig: Rig) -> None: ...

    def act(self, observation: Observation) -> Control | Waypoints: ...


def parse_action(value: Any) -> Control | Waypoints:
    """An agent's answer as an action, or `AgentFailure` saying what was wrong with it."""
    if isinstance(value, Control):
        numbers = (value.steer, value.throttle, value.brake)
        if not all(isinstance(v, int | float) and np.isfinite(v) for v in numbers):
            raise AgentFailure(f"control {value}: steer, throttle and brake must be finite numbers")
        return value.clipped()
    if isinstance(value, Waypoints):
        try:
            xy = np.asarray(value.xy_m, np.float64)
        except (TypeError, ValueError):
            raise AgentFailure("waypoints: not an (N, 2) array of numbers") from None
        if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) == 0:
            raise AgentFailure(f"waypoints: expected an (N>=1, 2) array, got shape {xy.shape}")
        if not np.isfinite(xy).all():
            raise AgentFailure("waypoints: contain NaN or infinity")
        return Waypoints(xy)
    raise AgentFailure(f"act returned {type(value).__name__}, expected Control or Waypoints")
