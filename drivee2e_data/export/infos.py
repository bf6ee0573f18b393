"""The info pickle VAD's nuScenes converter writes, from the logs: `{"infos": [...],
"metadata": {"version": ...}}`, one info per keyframe, in VAD's conventions so its training
code reads it unchanged:

- LiDAR frame with nuScenes' axes (x right, y forward; `export/common.py`);
- `gt_boxes` (N, 7): centre, size as width, length, height, and yaw as `-yaw - pi/2` (the
  mmdetection3d 0.x convention VAD's converter writes); `gt_velocity` (N, 2) in the LiDAR frame;
- trajectories as per-step offsets: `gt_ego_his_trajs` (2, 2), `gt_ego_fut_trajs` (6, 2) of the
  LiDAR origin, `gt_agent_fut_trajs` (N, 12); `gt_ego_fut_cmd` one-hot right, left, straight;
- `gt_ego_lcf_feat` (9): vx, vy (LiDAR frame), ax, ay (ego frame), yaw rate, length, width,
  speed, curvature (tan(steer) / wheelbase);
- `gt_agent_lcf_feat` (N, 9): x, y, yaw, vx, vy, width, length, height, category index;
- `gt_map_pts` (K, 20, 2), `gt_map_labels` (K,): the vector map labels of `loaders.map_labels`
  (divider 0, ped_crossing 1, boundary 2) in a 30 m (x) by 60 m (y) patch.

File paths point into the nuScenes export of the same clips (`drivee2e export nuscenes`), whose
tokens are the same.
"""

from __future__ import annotations

import io
import pickle
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivee2e_data import store
from drivee2e_data.ego_limits import WHEELBASE_SHARE
from drivee2e_data.export import common
from drivee2e_data.export.nuscenes import clips_for
from drivee2e_data.loaders import sample as labels
from drivee2e_data.loaders.clip import CLASSES, ClipLabels, read_clip
from drivee2e_data.loaders.map_labels import DEFAULT_PATCH_M, MapElements, map_elements, map_labels
from drivee2e_data.logs.reader import LogReader

HISTORY_STEPS, FUTURE_STEPS = 2, 6
INFO_KEYS = (
    "token", "prev", "next", "frame_idx", "scene_token", "lidar_path", "sweeps", "cams",
    "lidar2ego_translation", "lidar2ego_rotation", "ego2global_translation",
    "ego2global_rotation", "timestamp", "can_bus", "fut_valid_flag", "map_location",
    "gt_boxes", "gt_names", "gt_velocity", "num_lidar_pts", "num_radar_pts", "valid_flag",
    "gt_agent_fut_trajs", "gt_agent_fut_masks", "gt_agent_lcf_feat", "gt_agent_fut_yaw",
    "gt_agent_fut_goal", "gt_ego_his_trajs", "gt_ego_fut_trajs", "gt_ego_fut_masks",
    "gt_ego_fut_cmd", "gt_ego_lcf_feat", "gt_map_pts", "gt_map_labels",
)  # fmt: skip


def export_infos(
    root: Path,
    out: Path,
    nuscenes_root: Path,
    version: str = "v1.0-drivee2e",
    split: str = "train",
    split_name: str = "default",
    keyframe_every: int = 5,
    on_sample: Callable[[int], None] | None = None,
) -> int:
    """Write the split's infos to `out` (atomically); returns how many."""
    infos: list[dict[str, Any]] = []
    for scenario_id in clips_for(root, split, split_name):
        with LogReader(Path(root) / "logs" / f"{scenario_id}.mcap") as log:
            clip = read_clip(log)
            intersection_map = store.read_map(root, str(log.scenario_meta["map_id"]))
            offset = common.global_offset(intersection_map)
            elements = map_elements(intersection_map)
            frames = common.keyframes(
                clip.first_frame, clip.num_frames, keyframe_every, clip.sensor_every
            )
            for k in range(len(frames)):
                infos.append(
                    _info(
                        log, clip, frames, k, offset, elements, Path(nuscenes_root), keyframe_every
                    )
                )
                if on_sample is not None:
                    on_sample(1)
    buffer = io.BytesIO()
    pickle.dump({"infos": infos, "metadata": {"version": version}}, buffer, protocol=4)
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    store.write_bytes_atomic(Path(out), buffer.getvalue())
    return len(infos)


def _info(
    log: LogReader,
    clip: ClipLabels,
    frames: list[int],
    k: int,
    offset: NDArray[np.float64],
    elements: MapElements,
    nuscenes_root: Path,
    stride: int,
) -> dict[str, Any]:
    scenario_id, frame = clip.scenario_id, frames[k]
    row = clip.index(frame)
    t_ns = int(clip.t_ns[row])
    ego_to_global = labels.ego_to_world(clip, row)
    ego_to_global[:3, 3] += offset
    lidar_to_ego = common.nuscenes_lidar_to_ego(log.lidar_to_ego)
    lidar_to_global = ego_to_global @ lidar_to_ego
    token = common.token("sample", scenario_id, frame)
    info: dict[str, Any] = {
        "token": token,
        "prev": common.token("sample", scenario_id, frames[k - 1]) if k else "",
        "next": common.token("sample", scenario_id, frames[k + 1]) if k + 1 < len(frames) else "",
        "frame_idx": k,
        "scene_token": common.token("scene", scenario_id),
        "lidar_path": str(
            nuscenes_root / common.sample_file(scenario_id, "LIDAR_TOP", t_ns, "pcd.bin")
        ),
        "sweeps": [],
        "lidar2ego_translation": lidar_to_ego[:3, 3].tolist(),
        "lidar2ego_rotation": common.quaternion_list(lidar_to_ego[:3, :3]),
        "ego2global_translation": ego_to_global[:3, 3].tolist(),
        "ego2global_rotation": common.quaternion_list(ego_to_global[:3, :3]),
        "timestamp": t_ns // 1000,
        "can_bus": _can_bus(clip, row, offset),
        "fut_valid_flag": row + FUTURE_STEPS * stride < clip.num_frames,
        "map_location": str(log.scenario_meta["map_id"]),
        "cams": {},
    }
    for channel in log.cameras:
        camera = log.rig["cameras"][channel]
        camera_to_ego = np.array(camera["sensor_to_ego"])
        camera_to_lidar = np.linalg.inv(lidar_to_ego) @ camera_to_ego
        info["cams"][channel] = {
            "data_path": str(nuscenes_root / common.sample_file(scenario_id, channel, t_ns, "jpg")),
            "type": channel,
            "sample_data_token": common.token("sample_data", scenario_id, frame, channel),
            "sensor2ego_translation": camera_to_ego[:3, 3].tolist(),
            "sensor2ego_rotation": common.quaternion_list(camera_to_ego[:3, :3]),
            "ego2global_translation": ego_to_global[:3, 3].tolist(),
            "ego2global_rotation": common.quaternion_list(ego_to_global[:3, :3]),
            "timestamp": t_ns // 1000,
            "sensor2lidar_rotation": camera_to_lidar[:3, :3],  # points @ R.T + T
            "sensor2lidar_translation": camera_to_lidar[:3, 3],
            "cam_intrinsic": np.array(camera["intrinsic"]),
        }
    info.update(_boxes(clip, row, lidar_to_global, offset, stride))
    lidar_to_map = lidar_to_global.copy()
    lidar_to_map[:3, 3] -= offset
    # nuScenes' LiDAR axes: the 60 m along the heading are its y, the 30 m across its x
    map_points, map_classes = map_labels(elements, lidar_to_map, DEFAULT_PATCH_M[::-1])
    info.update(gt_map_pts=map_points.astype(np.float32), gt_map_labels=map_classes)
    info.update(_ego(clip, row, lidar_to_global, lidar_to_ego, offset, stride))
    return info


def _can_bus(clip: ClipLabels, row: int, offset: NDArray[np.float64]) -> NDArray[np.float64]:
    values = labels.can_bus(clip, row)
    values[:3] += offset
    return values


def _boxes(
    clip: ClipLabels,
    row: int,
    lidar_to_global: NDArray[np.float64],
    offset: NDArray[np.float64],
    stride: int,
) -> dict[str, Any]:
    """The boxes, their futures and features in VAD's conventions (LiDAR frame)."""
    boxes = clip.frame_boxes(row)
    count = len(boxes)
    world_pose = lidar_to_global.copy()  # the LiDAR's pose in the map's frame (boxes are there)
    world_pose[:3, 3] -= offset
    array = labels.box_array(boxes, world_pose)  # x, y, z, l, w, h, yaw, vx, vy
    gt_boxes = np.column_stack(
        [array[:, :3], array[:, 4:5], array[:, 3:4], array[:, 5:6], -array[:, 6:7] - np.pi / 2]
    )
    futures = np.zeros((count, FUTURE_STEPS, 2))
    masks = np.zeros((count, FUTURE_STEPS))
    yaw_steps = np.zeros((count, FUTURE_STEPS))
    rows = [row + stride * (j + 1) for j in range(FUTURE_STEPS)]
    for i, instance in enumerate(boxes.instance_ids):
        centre, yaw = array[i, :2], array[i, 6]
        for j, future_row in enumerate(rows):
            if (
                future_row >= clip.num_frames
                or instance not in clip.frame_boxes(future_row).instance_ids
            ):
                break
            future = clip.frame_boxes(future_row)
            m = future.instance_ids.index(instance)
            position = labels.to_frame(world_pose, future.centre_m[m : m + 1])[0, :2]
            heading = labels.yaw_in(world_pose, future.yaw_rad[m : m + 1])[0]
            futures[i, j], masks[i, j], yaw_steps[i, j] = position - centre, 1.0, heading - yaw
            centre, yaw = position, heading
    goals = np.full(count, 9.0)  # VAD's goal class: 9 static, else the motion's octant
    for i in range(count):
        travel = futures[i].sum(axis=0)
        if np.abs(travel).max() >= 1.0:
            goals[i] = (np.arctan2(travel[1], travel[0]) + np.pi) // (np.pi / 4)
    lcf = np.zeros((count, 9))
    if count:
        lcf[:, :2], lcf[:, 2], lcf[:, 3:5] = array[:, :2], array[:, 6], array[:, 7:9]
        lcf[:, 5], lcf[:, 6], lcf[:, 7] = array[:, 4], array[:, 3], array[:, 5]
        lcf[:, 8] = [common.NUSCENES_CATEGORY[CLASSES[c]][1] for c in boxes.labels]
    points = boxes.num_lidar_points + boxes.num_radar_points
    return {
        "gt_boxes": gt_boxes,
        "gt_names": np.array([common.NUSCENES_CATEGORY[CLASSES[c]][2] for c in boxes.labels]),
        "gt_velocity": array[:, 7:9],
        "num_lidar_pts": boxes.num_lidar_points.copy(),
        "num_radar_pts": boxes.num_radar_points.copy(),
        "valid_flag": points > 0,
        "gt_agent_fut_trajs": futures.reshape(count, -1).astype(np.float32),
        "gt_agent_fut_masks": masks.astype(np.float32),
        "gt_agent_lcf_feat": lcf.astype(np.float32),
        "gt_agent_fut_yaw": yaw_steps.astype(np.float32),
        "gt_agent_fut_goal": goals.astype(np.float32),
    }


def _ego(
    clip: ClipLabels,
    row: int,
    lidar_to_global: NDArray[np.float64],
    lidar_to_ego: NDArray[np.float64],
    offset: NDArray[np.float64],
    stride: int,
) -> dict[str, Any]:
    """The LiDAR origin's history and future as per-step offsets, command, features."""
    steps = np.arange(-HISTORY_STEPS, FUTURE_STEPS + 1) * stride + row
    positions = np.zeros((len(steps), 3))
    exists = (steps >= 0) & (steps < clip.num_frames)
    for k, step in enumerate(steps):
        pose = labels.ego_to_world(clip, int(np.clip(step, 0, clip.num_frames - 1))) @ lidar_to_ego
        positions[k] = pose[:3, 3] + offset
    local = labels.to_frame(lidar_to_global, positions)[:, :2]
    first = int(np.argmax(exists))
    local[~exists & (np.arange(len(steps)) < first)] = local[first]  # before the clip: stand still
    last = len(steps) - 1 - int(np.argmax(exists[::-1]))
    local[last + 1 :] = local[last]  # after the clip: stay at the last pose, masked
    offsets = np.diff(local, axis=0)
    history, future = offsets[:HISTORY_STEPS], offsets[HISTORY_STEPS:]
    status = labels.ego_status(clip, row)
    velocity_lidar = np.array([status[6], status[7], 0.0]) @ lidar_to_ego[:3, :3]
    length, width = clip.ego_size_m[:2]
    curvature = np.tan(clip.ego_steer_rad[row]) / (WHEELBASE_SHARE * length)
    return {
        "gt_ego_his_trajs": history.astype(np.float32),
        "gt_ego_fut_trajs": future.astype(np.float32),
        "gt_ego_fut_masks": exists[HISTORY_STEPS + 1 :].astype(np.float32),
        "gt_ego_fut_cmd": labels.command_one_hot(clip.ego_command[row]),
        "gt_ego_lcf_feat": np.array(
            [
                velocity_lidar[0],
                velocity_lidar[1],
                status[0],
                status[1],
                status[5],
                length,
                width,
                clip.ego_speed_mps[row],
                curvature,
            ],
            np.float32,
        ),
    }
