"""One clip's labels, read once from its log: the ego's state, the IMU, every frame's boxes and
traffic lights, the route and the rig. Everything a sample needs except the sensor data itself,
which the Dataset reads per frame.

All arrays are in the world frame (the map's local ENU, metres, radians); `loaders.sample`
turns them into the frames a sample uses. Reading a clip costs one pass over its small
per-frame chunks (the images and clouds are in chunks of their own, see `logs/writer.py`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.errors import LogFormatError
from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.scenario import AgentClass

# the 8 agent classes in label order: gt_labels index this tuple
CLASSES: tuple[str, ...] = tuple(c.value for c in AgentClass)
_LABEL_OF = {name: k for k, name in enumerate(CLASSES)}
# traffic-light state one-hot order (the light the ego's route passes)
LIGHT_STATES = ("RED", "YELLOW", "GREEN", "NONE")
_SMALL_TOPICS = (topics.EGO_STATE, topics.IMU, topics.OBJECTS, topics.TRAFFIC_LIGHTS)


@dataclass(frozen=True)
class FrameBoxes:
    """One frame's annotated boxes, world frame. `(M,)` or `(M, k)` arrays."""

    instance_ids: tuple[str, ...]
    labels: NDArray[np.int64]  # index into CLASSES
    size_m: NDArray[np.float64]  # (M, 3) length, width, height
    centre_m: NDArray[np.float64]  # (M, 3) box centre
    yaw_rad: NDArray[np.float64]  # (M,)
    velocity_mps: NDArray[np.float64]  # (M, 2)
    visibility: NDArray[np.int64]  # (M,) nuScenes token 0-4 (0: unseen)
    num_lidar_points: NDArray[np.int64]
    num_radar_points: NDArray[np.int64]

    def __len__(self) -> int:
        return len(self.instance_ids)


@dataclass(frozen=True)
class ClipLabels:
    """Per-frame arrays `(F, ...)` over the log's frames (index 0 is `first_frame`)."""

    scenario_id: str
    first_frame: int
    t_ns: NDArray[np.int64]
    ego_xyz_m: NDArray[np.float64]  # (F, 3) rear-axle centre on the ground
    ego_yaw_rad: NDArray[np.float64]
    ego_velocity_mps: NDArray[np.float64]  # (F, 2) world frame
    ego_speed_mps: NDArray[np.float64]
    ego_steer_rad: NDArray[np.float64]
    ego_command: NDArray[np.int64]  # 1 right, 2 left, 3 straight
    ego_size_m: NDArray[np.float64]  # (3,) length, width, height
    ego_rear_axle_to_centre_m: float
    imu_acceleration_mps2: NDArray[np.float64]  # (F, 3) ego frame, gravity included
    imu_angular_velocity_radps: NDArray[np.float64]  # (F, 3)
    # per frame; None between sensor frames (logs collected with `--sensor-hz` below 10)
    boxes: tuple[FrameBoxes | None, ...]
    ego_light: NDArray[np.int64]  # (F,) index into LIGHT_STATES
    route_xy_m: NDArray[np.float64]  # (W, 2) route waypoints, world frame; may be empty
    sensor_every: int = 1  # rows with sensor data and boxes: every n-th from row 0

    @property
    def num_frames(self) -> int:
        return len(self.t_ns)

    def index(self, frame: int) -> int:
        """Row of `frame` (a scenario frame number) in these arrays."""
        row = frame - self.first_frame
        if not 0 <= row < self.num_frames:
            raise IndexError(
                f"clip {self.scenario_id}: frame {frame} is not in the log (frames "
                f"{self.first_frame}-{self.first_frame + self.num_frames - 1})"
            )
        return row

    def frame_boxes(self, row: int) -> FrameBoxes:
        """The boxes of row `row`, which must be a sensor frame's."""
        boxes = self.boxes[row]
        if boxes is None:
            raise IndexError(
                f"clip {self.scenario_id}: frame {self.first_frame + row} has no boxes (sensors "
                f"and boxes are at every {self.sensor_every}th frame of this log)"
            )
        return boxes


def read_clip(log: LogReader) -> ClipLabels:
    """The labels of every frame of an open log."""
    count = log.num_frames
    by_topic: dict[str, list] = {topic: [None] * count for topic in _SMALL_TOPICS}
    sensor_rows = {frame - log.first_frame for frame in log.sensor_frames}
    row_of = {int(t): k for k, t in enumerate(log.t_ns)}
    for _, channel, message, decoded in log.decoded_messages(_SMALL_TOPICS):
        row = row_of.get(message.log_time)
        if row is None:
            raise LogFormatError(
                f"{log.path}: {channel.topic} has a message at t_ns {message.log_time}, "
                "which is no frame of the log"
            )
        by_topic[channel.topic][row] = decoded
    for topic, messages in by_topic.items():
        rows = sensor_rows if topic == topics.OBJECTS else range(count)
        missing = [row for row in rows if messages[row] is None]
        if missing:
            frame = log.first_frame + missing[0]
            raise LogFormatError(f"{log.path}: topic {topic} has no message at frame {frame}")
    states, imus = by_topic[topics.EGO_STATE], by_topic[topics.IMU]
    route = log.scenario_meta.get("route") or {}
    first = states[0]
    return ClipLabels(
        scenario_id=log.scenario_id,
        first_frame=log.first_frame,
        t_ns=log.t_ns.copy(),
        ego_xyz_m=np.array([(s.x, s.y, s.z) for s in states]),
        ego_yaw_rad=np.array([s.yaw for s in states]),
        ego_velocity_mps=np.array([(s.vx, s.vy) for s in states]),
        ego_speed_mps=np.array([s.speed for s in states]),
        ego_steer_rad=np.array([s.steer for s in states]),
        ego_command=np.array([s.command for s in states], np.int64),
        ego_size_m=np.array([first.length, first.width, first.height]),
        ego_rear_axle_to_centre_m=float(first.rear_axle_to_centre),
        imu_acceleration_mps2=np.array(
            [
                (m.linear_acceleration_x, m.linear_acceleration_y, m.linear_acceleration_z)
                for m in imus
            ]
        ),
        imu_angular_velocity_radps=np.array(
            [(m.angular_velocity_x, m.angular_velocity_y, m.angular_velocity_z) for m in imus]
        ),
        boxes=tuple(None if m is None else _frame_boxes(m) for m in by_topic[topics.OBJECTS]),
        ego_light=_ego_lights(by_topic[topics.TRAFFIC_LIGHTS], route.get("lane_ids") or []),
        route_xy_m=np.asarray(route.get("waypoints_xy_m") or np.zeros((0, 2)), np.float64),
        sensor_every=log.sensor_every,
    )


def _frame_boxes(message) -> FrameBoxes:  # type: ignore[no-untyped-def]
    objects = list(message.objects)
    return FrameBoxes(
        instance_ids=tuple(o.instance_id for o in objects),
        labels=np.array([_LABEL_OF[o.category] for o in objects], np.int64),
        size_m=np.array([(o.length, o.width, o.height) for o in objects]).reshape(-1, 3),
        centre_m=np.array([(o.x, o.y, o.z) for o in objects]).reshape(-1, 3),
        yaw_rad=np.array([o.yaw for o in objects], np.float64),
        velocity_mps=np.array([(o.vx, o.vy) for o in objects]).reshape(-1, 2),
        visibility=np.array([o.visibility for o in objects], np.int64),
        num_lidar_points=np.array([o.num_lidar_points for o in objects], np.int64),
        num_radar_points=np.array([o.num_radar_points for o in objects], np.int64),
    )


def _ego_lights(messages: list, route_lane_ids: list[str]) -> NDArray[np.int64]:
    """Per frame, the state of the signal that binds the ego (the log's `ego_signal_id`: the
    next signal-controlled stop line ahead along its route, none once past the last); NONE
    where none does. Logs written before that field (2026-11-24) give the first signal along
    the route at every frame."""
    none = LIGHT_STATES.index("NONE")
    result = np.full(len(messages), none, np.int64)
    per_frame = bool(messages) and "ego_signal_id" in messages[0].DESCRIPTOR.fields_by_name
    for row, message in enumerate(messages):
        if per_frame:
            bound = message.ego_signal_id
            state = next(
                (light.state for light in message.lights if light.signal_id == bound), None
            )
        else:
            controlling = {
                lane: light.state for light in message.lights for lane in light.controlled_lane_ids
            }
            state = next((controlling[k] for k in route_lane_ids if k in controlling), None)
        if state in LIGHT_STATES[:3]:
            result[row] = LIGHT_STATES.index(state)
    return result
