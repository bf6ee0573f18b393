"""What the nuScenes table export and the info-pickle export share: deterministic tokens, file
names, the export's global frame, nuScenes' LIDAR_TOP axes, and the class mapping.

- Tokens are 32 hex digits derived from what a record stands for (clip, frame, sensor,
  instance), so both exports agree and a rerun gives the same tokens.
- Global frame: nuScenes map masks put the global origin at a map image's lower-left corner,
  so the export's global frame is the map's local ENU frame shifted by `global_offset` (whole
  10 m, the map's extent plus a margin lands at positive coordinates). Stated per log record.
- LIDAR_TOP: nuScenes' LiDAR frame has x to the right and y forward (its calibration is a
  -90 degree yaw from the ego frame); planners trained on nuScenes (VAD, UniAD) assume it. The
  logs' LIDAR_TOP frame has the ego's axes, so exported points, boxes and trajectories are
  turned by +90 degrees about z, and the exported calibration says so.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.errors import DriveE2EError
from drivee2e_data.geometry import quaternion_from_rotation
from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.logs import topics

MAP_RESOLUTION_M = 0.1  # nuScenes map masks: 10 pixels a metre
MAP_MARGIN_M = 20.0
# our LIDAR_TOP axes (ego's) -> nuScenes' (x right, y forward): +90 degrees about z
TO_NUSCENES_LIDAR = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
# class -> (nuScenes category, its index in nuScenes' category table, detection name)
NUSCENES_CATEGORY = {
    "car": ("vehicle.car", 17, "car"),
    "van": ("vehicle.car", 17, "car"),  # nuScenes counts vans as cars
    "truck": ("vehicle.truck", 23, "truck"),
    "bus": ("vehicle.bus.rigid", 16, "bus"),
    "pedestrian": ("human.pedestrian.adult", 2, "pedestrian"),
    "cyclist": ("vehicle.bicycle", 14, "bicycle"),  # nuScenes boxes the bicycle with its rider
    "tricyclist": ("vehicle.bicycle", 14, "bicycle"),
    "motorcyclist": ("vehicle.motorcycle", 21, "motorcycle"),
}
MOVING_MPS = 0.5  # attribute moving/stopped (standing) above/below this speed


def token(*parts: object) -> str:
    """A nuScenes-style token (32 hex digits) for the record these parts name."""
    return hashlib.sha256("/".join(map(str, parts)).encode()).hexdigest()[:32]


def sample_file(scenario_id: str, channel: str, t_ns: int, extension: str) -> str:
    """A keyframe file's path under the nuScenes root, as nuScenes names them."""
    return f"samples/{channel}/{scenario_id}__{channel}__{t_ns // 1000}.{extension}"


def map_file(map_id: str) -> str:
    return f"maps/{map_id}.png"


def map_bounds(
    intersection_map: IntersectionMap,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(min xy, max xy) of the map's lanes, areas and crosswalks."""
    points = [lane.left_boundary_m[:, :2] for lane in intersection_map.lanes]
    points += [lane.right_boundary_m[:, :2] for lane in intersection_map.lanes]
    points += [
        a.polygon_m[:, :2] for a in (*intersection_map.drivable_areas, *intersection_map.crosswalks)
    ]
    stacked = np.concatenate(points)
    return stacked.min(axis=0), stacked.max(axis=0)


def global_offset(intersection_map: IntersectionMap) -> NDArray[np.float64]:
    """(3,) added to world coordinates to get the export's global frame."""
    low, _ = map_bounds(intersection_map)
    shift = -10.0 * np.floor((low - MAP_MARGIN_M) / 10.0)
    return np.array([shift[0], shift[1], 0.0])


def quaternion_list(rotation: NDArray[np.float64]) -> list[float]:
    """A rotation matrix as the [w, x, y, z] list nuScenes tables hold."""
    return [float(v) for v in quaternion_from_rotation(rotation)]


def nuscenes_lidar_to_ego(lidar_to_ego: NDArray[np.float64]) -> NDArray[np.float64]:
    """(4, 4) the nuScenes-axes LIDAR_TOP frame's pose in the ego frame."""
    pose = np.array(lidar_to_ego, np.float64).copy()
    pose[:3, :3] = pose[:3, :3] @ TO_NUSCENES_LIDAR.T
    return pose


def attribute(class_name: str, speed_mps: float) -> str:
    """nuScenes attribute name of an agent of this class at this speed."""
    if class_name == "pedestrian":
        return "pedestrian.moving" if speed_mps > MOVING_MPS else "pedestrian.standing"
    if class_name in ("cyclist", "tricyclist", "motorcyclist"):
        return "cycle.with_rider"
    return "vehicle.moving" if speed_mps > MOVING_MPS else "vehicle.stopped"


def keyframes(first_frame: int, count: int, every: int, sensor_every: int = 1) -> list[int]:
    """The frames exported as samples: every `every`-th logged frame, which must be sensor
    frames (a log collected with `--sensor-hz 2` has them at every 5th)."""
    if every % sensor_every:
        rate = topics.FRAME_RATE_HZ // sensor_every
        raise DriveE2EError(
            f"a sample every {every} frames: this log has sensor data at every {sensor_every}th "
            f"frame only (collected at {rate} Hz); export every multiple of it"
        )
    return list(range(first_frame, first_frame + count, every))


def check_out(out: Path) -> None:
    if out.exists():
        raise DriveE2EError(f"{out}: already exists; delete it or choose another --out")
