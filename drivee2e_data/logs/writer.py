"""Writes one clip's log: `<scenario_id>.mcap`, zstd chunks, the scenario meta and the rig as
metadata records, every per-frame topic stamped with the frame's time.

The log is written under a temporary name in the same folder (`.<name>.<pid>.partial`) and
renamed only when complete, so a file under the final name is always a whole log.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from mcap.well_known import MessageEncoding
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from mcap_protobuf.schema import register_schema

from drivee2e_data import __version__, store
from drivee2e_data.binding import binding_signals, front_bumper
from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.logs import messages, topics
from drivee2e_data.scenario import Scenario
from drivee2e_data.sensors.ego_state import EgoMotion
from drivee2e_data.sensors.rig import Rig
from drivee2e_data.sensors.suite import SensorFrame

CHUNK_BYTES = 4 * 1024 * 1024  # an upper bound: every frame ends its chunks (see `write`)
PARTIAL_SUFFIX = ".partial"


def partial_path(final: Path) -> Path:
    return final.with_name(f".{final.name}.{os.getpid()}{PARTIAL_SUFFIX}")


def rig_document(rig: Rig) -> dict[str, Any]:
    """Calibrations as JSON: per sensor its sensor-to-ego pose; cameras with K and size."""
    return {
        "cameras": {
            c.name: {
                "width": c.width,
                "height": c.height,
                "intrinsic": c.intrinsic.tolist(),
                "sensor_to_ego": c.sensor_to_ego.tolist(),
            }
            for c in rig.cameras
        },
        "lidar": {
            rig.lidar.name: {
                "sensor_to_ego": rig.lidar.sensor_to_ego.tolist(),
                "channels": rig.lidar.channels,
                "range_m": rig.lidar.range_m,
                "elevation_deg": [rig.lidar.upper_deg, rig.lidar.lower_deg],
                "azimuth_step_deg": rig.lidar.azimuth_step_deg,
            }
        },
        "radars": {
            r.name: {
                "sensor_to_ego": r.sensor_to_ego.tolist(),
                "range_m": r.range_m,
                "horizontal_fov_deg": r.horizontal_fov_deg,
            }
            for r in rig.radars
        },
    }


class LogWriter:
    """Use as a context manager: the log appears under `path` only if the block completes."""

    def __init__(
        self,
        path: Path,
        scenario: Scenario,
        intersection_map: IntersectionMap,
        rig: Rig,
        motion: EgoMotion,
        collection: dict[str, str],
        camera_labels: dict[str, str] | None = None,
    ) -> None:
        self.path, self.partial = path, partial_path(path)
        self.intersection_map, self.rig, self.motion = intersection_map, rig, motion
        self.signal_lanes = messages.signal_lanes(intersection_map)  # the same at every frame
        # the signal binding the ego at each frame of the clip, from its logged pose and route
        route = scenario.route.lane_ids if scenario.route is not None else ()
        ego = scenario.ego
        front = front_bumper(ego.xy_m, ego.yaw_rad, float(motion.size_m[0]))
        self.binding = binding_signals(intersection_map, route, front)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.partial, "wb")
        self._writer = McapWriter(
            self._file, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD
        )
        self._writer.start(profile="", library=f"drivee2e-data {__version__}")
        self._channels: dict[str, int] = {}  # topic -> channel id
        self._schemas: dict[str, int] = {}  # message type -> schema id
        self._writer.add_metadata(
            topics.SCENARIO_METADATA,
            {"meta": json.dumps(store.meta_document(scenario), sort_keys=True)},
        )
        self._writer.add_metadata(topics.RIG_METADATA, {"rig": json.dumps(rig_document(rig))})
        self._writer.add_metadata(
            topics.COLLECTION_METADATA, {"drivee2e_version": __version__, **collection}
        )
        if camera_labels:
            self._writer.add_metadata(topics.CAMERA_LABELS_METADATA, camera_labels)
        self.sensors = {c.name: c.sensor_to_ego for c in rig.cameras}
        self.sensors[rig.lidar.name] = rig.lidar.sensor_to_ego
        self.sensors.update({r.name: r.sensor_to_ego for r in rig.radars})
        self.t_ns: list[int] = []  # of the frames written
        self.first_frame = 0

    def write(self, frame: SensorFrame) -> None:
        """All topics of one frame, each with log time and publish time = the frame's time.

        A frame is written as three chunks: the camera images, then the LiDAR and radar clouds,
        then everything else. A reader that wants one kind (a training loader reading images,
        an index reading ego states) then inflates only that chunk: the LiDAR is four fifths
        of a frame's bytes and compresses, the JPEGs do not.
        """
        t = frame.t_ns

        def put(topic: str, message: Any) -> None:
            self._writer.add_message(
                self._channel(topic, message),
                log_time=t,
                data=message.SerializeToString(),
                publish_time=t,
            )

        for camera in self.rig.cameras:
            put(
                topics.image_topic(camera.name),
                messages.compressed_image(t, camera.name, frame.jpeg[camera.name]),
            )
        self._writer.flush()
        if frame.camera_labels:  # a chunk of their own: the loader's image reads skip them
            for camera, images in frame.camera_labels.items():
                for kind, png in images.items():
                    put(topics.camera_label_topic(camera, kind), messages.png_image(t, camera, png))
            self._writer.flush()
        put(topics.LIDAR, messages.lidar_cloud(t, self.rig.lidar.name, frame.lidar))
        for radar in self.rig.radars:
            put(
                topics.radar_topic(radar.name),
                messages.radar_cloud(t, radar.name, frame.radars[radar.name]),
            )
        self._writer.flush()
        if not self.t_ns:
            self.first_frame = frame.frame
            put(topics.MAP, messages.map_scene(t, self.intersection_map))
        for camera in self.rig.cameras:
            put(topics.camera_info_topic(camera.name), messages.camera_calibration(t, camera))
        put(topics.TF, messages.frame_transforms(t, frame.ego_to_world, self.sensors))
        put(topics.GNSS, messages.location_fix(t, frame, self.motion))
        put(topics.IMU, messages.imu_message(t, frame))
        put(topics.EGO_STATE, messages.ego_state(t, self.motion, frame.frame))
        put(topics.OBJECTS, messages.object_annotations(t, frame))
        put(topics.SCENE, messages.scene_boxes(t, frame))
        put(
            topics.TRAFFIC_LIGHTS,
            messages.traffic_lights(t, frame, self.signal_lanes, self.binding[frame.frame]),
        )
        put(topics.BEV, messages.compressed_image(t, topics.EGO_FRAME, frame.bev_jpeg))
        self._writer.flush()
        self.t_ns.append(int(t))

    def _channel(self, topic: str, message: Any) -> int:
        """The topic's channel, registered with its message's schema on first use."""
        if topic not in self._channels:
            kind = type(message).DESCRIPTOR.full_name
            if kind not in self._schemas:
                self._schemas[kind] = register_schema(self._writer, type(message))
            self._channels[topic] = self._writer.register_channel(
                topic=topic,
                message_encoding=MessageEncoding.Protobuf,
                schema_id=self._schemas[kind],
            )
        return self._channels[topic]

    def finish(self) -> None:
        """The frame list, index and footer, flushed to disk, then the rename that makes the
        log final."""
        self._writer.add_metadata(
            topics.FRAMES_METADATA,
            {
                "first_frame": str(self.first_frame),
                "count": str(len(self.t_ns)),
                "t_ns": json.dumps(self.t_ns),
            },
        )
        self._writer.finish()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        os.replace(self.partial, self.path)

    def abort(self) -> None:
        self._file.close()
        self.partial.unlink(missing_ok=True)

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, exc_type: object, *rest: object) -> None:
        if exc_type is None:
            self.finish()
        else:
            self.abort()
