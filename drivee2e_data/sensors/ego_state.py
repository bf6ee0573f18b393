"""The ego's state per frame from its logged track: the nuScenes ego frame (origin at the rear
axle on the ground), speed, longitudinal acceleration, yaw rate, the controls a kinematic
bicycle would need to follow the path, and the high-level command planners are given.

Logs carry no controls, so steer, throttle and brake are derived: steer from the bicycle model
(tan(steer) = wheelbase * yaw_rate / speed), throttle and brake from the longitudinal
acceleration scaled by the car's typical limits. They are labels of the motion, not of a driver.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.ego_limits import (  # the same limits as the simulator's car
    FULL_BRAKE_MPS2,
    FULL_THROTTLE_MPS2,
    MAX_STEER_RAD,
    REAR_AXLE_SHARE,
    WHEELBASE_SHARE,
)
from drivee2e_data.scenario import Scenario, Track
from drivee2e_data.sensors.imu_gnss import imu

STEER_MIN_SPEED_MPS = 1.0  # below this the yaw rate says little about the wheel angle
# the command looks 3 s ahead, as nuScenes-trained planners do (ego_fut_cmd)
COMMAND_HORIZON_FRAMES = 30
COMMAND_LATERAL_M = 2.0
# the open-loop future: 6 waypoints at 2 Hz over 3 s
FUTURE_STEPS = 6
FUTURE_STRIDE_FRAMES = 5


class Command(enum.IntEnum):
    """High-level command; values as the `drivee2e.Command` protobuf enum."""

    RIGHT = 1
    LEFT = 2
    STRAIGHT = 3


@dataclass(frozen=True)
class EgoMotion:
    """Per-frame arrays `(T,)` of the ego, world frame (ENU metres, radians, seconds)."""

    t_ns: NDArray[np.int64]
    x_m: NDArray[np.float64]  # rear-axle centre
    y_m: NDArray[np.float64]
    z_m: NDArray[np.float64]  # ground under the rear axle
    yaw_rad: NDArray[np.float64]
    vx_mps: NDArray[np.float64]
    vy_mps: NDArray[np.float64]
    speed_mps: NDArray[np.float64]
    acceleration_mps2: NDArray[np.float64]  # longitudinal
    yaw_rate_radps: NDArray[np.float64]
    steer_rad: NDArray[np.float64]
    throttle: NDArray[np.float64]
    brake: NDArray[np.float64]
    command: NDArray[np.int64]  # Command values
    size_m: NDArray[np.float64]  # (3,) length, width, height of the ego's box
    rear_axle_to_centre_m: float

    def ego_to_world(self, frame: int) -> NDArray[np.float64]:
        """(4, 4) pose of the ego frame in the world at `frame`."""
        return se3(self.x_m[frame], self.y_m[frame], self.z_m[frame], self.yaw_rad[frame])


def se3(x: float, y: float, z: float, yaw_rad: float) -> NDArray[np.float64]:
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    matrix = np.eye(4)
    matrix[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    matrix[:3, 3] = (x, y, z)
    return matrix


def ego_motion(scenario: Scenario) -> EgoMotion:
    """The ego's motion over the whole clip; the ego must be valid at every frame."""
    ego = scenario.ego
    if ego is None:
        raise ValueError(f"scenario {scenario.scenario_id!r} has no ego; run drivee2e curate")
    if not ego.valid.all():
        missing = int((~ego.valid).sum())
        raise ValueError(
            f"scenario {scenario.scenario_id!r}: ego {ego.track_id!r} is missing at {missing} "
            "frames; collection needs the ego at every frame"
        )
    return _motion(scenario.t_ns, ego)


def _motion(t_ns: NDArray[np.int64], ego: Track) -> EgoMotion:
    yaw = np.unwrap(ego.yaw_rad)
    heading = np.stack([np.cos(yaw), np.sin(yaw)], -1)
    length = float(np.median(ego.length_m))
    back = REAR_AXLE_SHARE * length
    xy = ego.xy_m - back * heading
    velocity = np.stack([ego.vx_mps, ego.vy_mps], -1)
    speed = np.hypot(velocity[:, 0], velocity[:, 1])
    # the IMU's own differences: longitudinal acceleration and yaw rate as the IMU reports them
    vehicle_acceleration, angular_velocity = imu(ego)
    acceleration, yaw_rate = vehicle_acceleration[:, 0], angular_velocity[:, 2]
    wheelbase = WHEELBASE_SHARE * length
    steer = np.where(
        speed > STEER_MIN_SPEED_MPS,
        np.arctan(wheelbase * yaw_rate / np.maximum(speed, STEER_MIN_SPEED_MPS)),
        0.0,
    ).clip(-MAX_STEER_RAD, MAX_STEER_RAD)
    return EgoMotion(
        t_ns=np.asarray(t_ns, np.int64),
        x_m=xy[:, 0],
        y_m=xy[:, 1],
        z_m=ego.z_m - 0.5 * ego.height_m,
        yaw_rad=yaw,
        vx_mps=velocity[:, 0],
        vy_mps=velocity[:, 1],
        speed_mps=speed,
        acceleration_mps2=acceleration,
        yaw_rate_radps=yaw_rate,
        steer_rad=steer,
        throttle=(acceleration / FULL_THROTTLE_MPS2).clip(0.0, 1.0),
        brake=(-acceleration / FULL_BRAKE_MPS2).clip(0.0, 1.0),
        command=commands(xy, yaw),
        size_m=np.array([length, float(np.median(ego.width_m)), float(np.median(ego.height_m))]),
        rear_axle_to_centre_m=back,
    )


def to_ego_frame(
    points_xy_m: NDArray[np.float64], x_m: float, y_m: float, yaw_rad: float
) -> NDArray[np.float64]:
    """(N, 2) world points in the ego frame at pose (x, y, yaw)."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    relative = np.asarray(points_xy_m, np.float64) - (x_m, y_m)
    return np.stack(
        [relative[:, 0] * c + relative[:, 1] * s, -relative[:, 0] * s + relative[:, 1] * c], -1
    )


def commands(xy_m: NDArray[np.float64], yaw_rad: NDArray[np.float64]) -> NDArray[np.int64]:
    """Per frame: LEFT or RIGHT when the ego will be more than 2 m to that side 3 s ahead (or at
    the clip's end, if nearer), else STRAIGHT."""
    last = len(xy_m) - 1
    result = np.empty(len(xy_m), np.int64)
    for frame in range(len(xy_m)):
        ahead = xy_m[min(frame + COMMAND_HORIZON_FRAMES, last)][None]
        lateral = to_ego_frame(ahead, *xy_m[frame], yaw_rad[frame])[0, 1]
        if lateral >= COMMAND_LATERAL_M:
            result[frame] = Command.LEFT
        elif lateral <= -COMMAND_LATERAL_M:
            result[frame] = Command.RIGHT
        else:
            result[frame] = Command.STRAIGHT
    return result


def future_path(
    x_m: NDArray[np.float64], y_m: NDArray[np.float64], yaw_rad: NDArray[np.float64], frame: int
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The 2 Hz future over 3 s, `(6, 2)` in the ego frame of `frame`, and which steps exist
    (steps past the clip's end are masked, their positions zero)."""
    steps = frame + FUTURE_STRIDE_FRAMES * np.arange(1, FUTURE_STEPS + 1)
    mask = steps < len(x_m)
    path = np.zeros((FUTURE_STEPS, 2))
    if mask.any():
        ahead = np.stack([x_m[steps[mask]], y_m[steps[mask]]], -1)
        path[mask] = to_ego_frame(ahead, x_m[frame], y_m[frame], yaw_rad[frame])
    return path, mask
