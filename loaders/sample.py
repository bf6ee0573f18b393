"""A sample's labels as numpy arrays, from a clip's labels and the rig: poses, boxes in the
LiDAR frame, the ego's history and future, agents' futures, command, status and CAN bus.

Frames: world = the map's local ENU; ego = nuScenes ego frame at the rear axle (x forward,
y left, z up); LiDAR = the LIDAR_TOP sensor frame as logged (for this rig the ego's axes,
0.95 m ahead and 1.85 m up). Trajectories are at 2 Hz (every 5th frame of the 10 Hz log).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.geometry import next_waypoint, quaternion_from_rotation, wrap_angle
from drivee2e_data.loaders.clip import ClipLabels, FrameBoxes
from drivee2e_data.sensors.ego_state import FUTURE_STRIDE_FRAMES, se3

TRAJECTORY_STRIDE_FRAMES = FUTURE_STRIDE_FRAMES  # 2 Hz
TARGET_POINT_MIN_M = 10.0  # the route's next waypoint at least this far ahead of the ego


@dataclass(frozen=True)
class Horizons:
    """How many 2 Hz steps of history and future a sample carries."""

    history_steps: int = 4  # 2.0 s
    future_steps: int = 6  # 3.0 s

    @classmethod
    def of(cls, history_s: float, future_s: float) -> Horizons:
        period_s = TRAJECTORY_STRIDE_FRAMES * 0.1
        history, future = round(history_s / period_s), round(future_s / period_s)
        if history < 0 or future < 1:
            raise ValueError(
                f"history_s={history_s}, future_s={future_s}: expected history >= 0 and a "
                f"future of at least one {period_s:.1f} s step"
            )
        return cls(history, future)


def ego_to_world(clip: ClipLabels, row: int) -> NDArray[np.float64]:
    """(4, 4) pose of the ego frame at `row` in the world."""
    x, y, z = clip.ego_xyz_m[row]
    return se3(x, y, z, clip.ego_yaw_rad[row])


def to_frame(pose: NDArray[np.float64], points_m: NDArray[np.float64]) -> NDArray[np.float64]:
    """World points `(N, 3)` in the frame whose pose in the world is `pose` (4, 4)."""
    rotation, translation = pose[:3, :3], pose[:3, 3]
    return (np.asarray(points_m, np.float64) - translation) @ rotation


def yaw_in(pose: NDArray[np.float64], yaw_world_rad: NDArray[np.float64]) -> NDArray[np.float64]:
    """World headings as headings in the frame of `pose` (rotation about z), wrapped."""
    return wrap_angle(np.asarray(yaw_world_rad) - np.arctan2(pose[1, 0], pose[0, 0]))


def rotate_in(pose: NDArray[np.float64], vectors_xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """World planar vectors `(N, 2)` in the axes of `pose`."""
    vectors = np.column_stack([vectors_xy, np.zeros(len(vectors_xy))])
    return (vectors @ pose[:3, :3])[:, :2]


def box_array(boxes: FrameBoxes, lidar_to_world: NDArray[np.float64]) -> NDArray[np.float64]:
    """(M, 9) x, y, z (centre), length, width, height, yaw, vx, vy in the LiDAR frame."""
    result = np.zeros((len(boxes), 9))
    if len(boxes):
        result[:, :3] = to_frame(lidar_to_world, boxes.centre_m)
        result[:, 3:6] = boxes.size_m
        result[:, 6] = yaw_in(lidar_to_world, boxes.yaw_rad)
        result[:, 7:9] = rotate_in(lidar_to_world, boxes.velocity_mps)
    return result


def _steps(
    row: int, count: int, sign: int, num_frames: int
) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Rows `count` 2 Hz steps before (sign -1, oldest first) or after (sign +1) `row`, and
    which exist; missing rows are clamped to a valid one (their values are masked)."""
    offsets = np.arange(1, count + 1) * TRAJECTORY_STRIDE_FRAMES
    rows = row - offsets[::-1] if sign < 0 else row + offsets
    valid = (rows >= 0) & (rows < num_frames)
    return np.clip(rows, 0, num_frames - 1), valid


def ego_trajectory(
    clip: ClipLabels, row: int, count: int, sign: int
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The ego's rear-axle positions `(count, 2)` at 2 Hz in its frame at `row` (history
    oldest first when `sign` is -1), zero where the log has no such frame, and the mask."""
    rows, valid = _steps(row, count, sign, clip.num_frames)
    points = to_frame(ego_to_world(clip, row), clip.ego_xyz_m[rows])[:, :2]
    points[~valid] = 0.0
    return points, valid


def agent_futures(
    clip: ClipLabels, row: int, steps: int, lidar_to_world: NDArray[np.float64]
) -> dict[str, NDArray]:
    """Each box's future at 2 Hz: centre relative to its current centre in LiDAR axes
    `(M, steps, 2)`, heading in the LiDAR frame `(M, steps)`, the mask `(M, steps)`, and the
    future boxes in the current ego frame `(M, steps, 5)`: x, y, length, width, yaw (for the
    collision metric)."""
    boxes = clip.frame_boxes(row)
    count = len(boxes)
    rows, exists = _steps(row, steps, +1, clip.num_frames)
    trajectories = np.zeros((count, steps, 2))
    headings = np.zeros((count, steps))
    masks = np.zeros((count, steps), bool)
    ego_boxes = np.zeros((count, steps, 5))
    world_to_ego = ego_to_world(clip, row)
    for step, (future_row, ok) in enumerate(zip(rows, exists, strict=True)):
        if not ok:
            continue
        future = clip.frame_boxes(future_row)
        where = {instance: k for k, instance in enumerate(future.instance_ids)}
        for k, instance in enumerate(boxes.instance_ids):
            j = where.get(instance)
            if j is None:
                continue
            masks[k, step] = True
            delta = future.centre_m[j, :2] - boxes.centre_m[k, :2]
            trajectories[k, step] = rotate_in(lidar_to_world, delta[None])[0]
            headings[k, step] = yaw_in(lidar_to_world, future.yaw_rad[j : j + 1])[0]
            ego_boxes[k, step, :2] = to_frame(world_to_ego, future.centre_m[j : j + 1])[0, :2]
            ego_boxes[k, step, 2:4] = future.size_m[j, :2]
            ego_boxes[k, step, 4] = yaw_in(world_to_ego, future.yaw_rad[j : j + 1])[0]
    return {
        "gt_agent_fut_trajs": trajectories,
        "gt_agent_fut_yaw": headings,
        "gt_agent_fut_masks": masks,
        "gt_agent_fut_boxes": ego_boxes,
    }


def command_one_hot(command: int) -> NDArray[np.float32]:
    """(3,) right, left, straight, as nuScenes-trained planners read `ego_fut_cmd`."""
    one_hot = np.zeros(3, np.float32)
    one_hot[int(command) - 1] = 1.0
    return one_hot


def ego_status(clip: ClipLabels, row: int) -> NDArray[np.float64]:
    """(10,) acceleration xyz, angular velocity xyz (IMU, ego frame), velocity xyz (ego frame),
    steering angle (front wheels, rad, positive left)."""
    velocity = rotate_in(ego_to_world(clip, row), clip.ego_velocity_mps[row : row + 1])[0]
    return np.concatenate(
        [
            clip.imu_acceleration_mps2[row],
            clip.imu_angular_velocity_radps[row],
            [velocity[0], velocity[1], 0.0],
            [clip.ego_steer_rad[row]],
        ]
    )


def can_bus(clip: ClipLabels, row: int) -> NDArray[np.float64]:
    """(18,) as BEVFormer and UniAD lay it out: translation (3), rotation quaternion w, x, y, z
    (4), acceleration (3), angular velocity (3), velocity (3), yaw in radians, yaw in degrees."""
    pose = ego_to_world(clip, row)
    status = ego_status(clip, row)
    yaw = float(clip.ego_yaw_rad[row])
    return np.concatenate(
        [
            pose[:3, 3],
            quaternion_from_rotation(pose[:3, :3]),
            status[0:3],
            status[3:6],
            status[6:9],
            [yaw, np.rad2deg(yaw)],
        ]
    )


def target_point(clip: ClipLabels, row: int) -> NDArray[np.float64]:
    """(2,) the route's next waypoint at least `TARGET_POINT_MIN_M` ahead of the ego, in its
    frame (the last waypoint near the route's end; zeros without a route)."""
    route = clip.route_xy_m
    if len(route) == 0:
        return np.zeros(2)
    waypoint = next_waypoint(route, clip.ego_xyz_m[row, :2], TARGET_POINT_MIN_M)
    return to_frame(ego_to_world(clip, row), np.append(waypoint, 0.0)[None])[0, :2]


def camera_matrices(
    intrinsic: NDArray[np.float64],
    camera_to_ego: NDArray[np.float64],
    lidar_to_ego: NDArray[np.float64],
) -> NDArray[np.float64]:
    """(4, 4) lidar2img: LiDAR points `[x, y, z, 1]` to `[u*d, v*d, d, 1]` pixels."""
    intrinsic_4 = np.eye(4)
    intrinsic_4[:3, :3] = intrinsic
    return intrinsic_4 @ np.linalg.inv(camera_to_ego) @ lidar_to_ego
