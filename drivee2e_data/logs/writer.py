"""Writes one clip's log: `<scenario_id>.mcap`, zstd chunks, the scenario meta and the rig as
metadata records, every per-frame topic stamped with the frame's time.

A frame is encoded into finished, compressed chunks (`FrameEncoder.encode`, `chunks.py`) that
the log's file takes as they are (`container.py`), so a worker collecting a segment of a clip
compresses its frames and writing the clip's log from its segments is a copy.

The log is written under a temporary name in the same folder (`.<name>.<pid>.partial`) and
renamed only when complete, so a file under the final name is always a whole log.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from drivee2e_data import __version__, store
from drivee2e_data.binding import binding_signals, front_bumper
from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.logs import messages, schemas, topics
from drivee2e_data.logs.chunks import ChannelTable, FinishedChunk, finish_chunk
from drivee2e_data.logs.container import McapContainer
from drivee2e_data.logs.writeback import Writeback
from drivee2e_data.scenario import Scenario
from drivee2e_data.sensors.ego_state import EgoMotion
from drivee2e_data.sensors.rig import Rig
from drivee2e_data.sensors.suite import SensorFrame, StateFrame

PARTIAL_SUFFIX = ".partial"


@dataclass(frozen=True)
class EncodedFrame:
    """One frame's finished chunks as `FrameEncoder.encode` makes them, ready to write."""

    frame: int
    t_ns: int
    chunks: tuple[FinishedChunk, ...]


def log_channels(rig: Rig, camera_label_kinds: tuple[str, ...] = ()) -> ChannelTable:
    """Every topic a log of this rig carries, with its message class, in the order a frame
    writes them (channel ids 1, 2, ... in this order, whatever frames a writer sees)."""
    cameras = [c.name for c in rig.cameras]
    return ChannelTable.of(
        [
            *((topics.image_topic(c), CompressedImage) for c in cameras),
            *(
                (topics.camera_label_topic(c, kind), CompressedImage)
                for c in cameras
                for kind in camera_label_kinds
            ),
            (topics.LIDAR, PointCloud),
            *((topics.radar_topic(r.name), PointCloud) for r in rig.radars),
            (topics.MAP, SceneUpdate),
            *((topics.camera_info_topic(c), CameraCalibration) for c in cameras),
            *((topics.exposure_topic(c), schemas.CameraExposure) for c in cameras),
            (topics.TF, FrameTransforms),
            (topics.GNSS, LocationFix),
            (topics.IMU, schemas.Imu),
            (topics.EGO_STATE, schemas.EgoState),
            (topics.OBJECTS, schemas.ObjectAnnotations),
            (topics.SCENE, SceneUpdate),
            (topics.TRAFFIC_LIGHTS, schemas.TrafficLights),
            (topics.BEV, CompressedImage),
        ]
    )


def label_kinds(camera_labels: dict[str, str] | None) -> tuple[str, ...]:
    """The dense label kinds a log's `drivee2e.camera_labels` record names (() for none)."""
    return tuple(camera_labels["kinds"].split(",")) if camera_labels else ()


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


class FrameEncoder:
    """Turns a clip's captured frames into finished chunks (`encode`); holds what is the same at
    every frame: the channels, the rig, the map's signal lanes, the ego's binding signals."""

    def __init__(
        self,
        scenario: Scenario,
        intersection_map: IntersectionMap,
        rig: Rig,
        motion: EgoMotion,
        first_frame: int = 0,
        camera_label_kinds: tuple[str, ...] = (),
    ) -> None:
        self.intersection_map, self.rig, self.motion = intersection_map, rig, motion
        self.first_frame = first_frame
        self.channels = log_channels(rig, camera_label_kinds)
        self.signal_lanes = messages.signal_lanes(intersection_map)  # the same at every frame
        # the signal binding the ego at each frame of the clip, from its logged pose and route
        route = scenario.route.lane_ids if scenario.route is not None else ()
        ego = scenario.ego
        front = front_bumper(ego.xy_m, ego.yaw_rad, float(motion.size_m[0]))
        self.binding = binding_signals(intersection_map, route, front)
        self.sensors = {c.name: c.sensor_to_ego for c in rig.cameras}
        self.sensors[rig.lidar.name] = rig.lidar.sensor_to_ego
        self.sensors.update({r.name: r.sensor_to_ego for r in rig.radars})

    def _message(self, topic: str, message: Any) -> tuple[int, bytes]:
        """A message as a chunk takes it: its topic's channel id and its bytes."""
        return self.channels.channel_id(topic), message.SerializeToString()

    def encode_state(self, frame: StateFrame) -> EncodedFrame:
        """A frame between sensor frames (`collect --sensor-hz`): the pose, GNSS, IMU, ego state
        and traffic lights, one chunk."""
        t = frame.t_ns
        chunk: list[tuple[int, bytes]] = []

        def put(topic: str, message: Any) -> None:
            chunk.append(self._message(topic, message))

        put(topics.TF, messages.frame_transforms(t, frame.ego_to_world, self.sensors))
        put(topics.GNSS, messages.location_fix(t, frame, self.motion))
        put(topics.IMU, messages.imu_message(t, frame))
        put(topics.EGO_STATE, messages.ego_state(t, self.motion, frame.frame))
        put(
            topics.TRAFFIC_LIGHTS,
            messages.traffic_lights(t, frame, self.signal_lanes, self.binding[frame.frame]),
        )
        return EncodedFrame(frame.frame, int(t), (finish_chunk(chunk, int(t)),))

    def encode(self, frame: SensorFrame | StateFrame) -> EncodedFrame:
        """One frame's messages as finished chunks, in the order they are written.

        A frame is written as three chunks: the camera images, then the LiDAR and radar clouds,
        then everything else. A reader that wants one kind (a training loader reading images,
        an index reading ego states) then inflates only that chunk: the LiDAR is four fifths
        of a frame's bytes and compresses, the JPEGs do not. Encoding needs no open file, so a
        worker can encode frames of a clip's segment and another process write them
        (`collect/segments.py`); the log is the same bytes either way.
        """
        if isinstance(frame, StateFrame):
            return self.encode_state(frame)
        t = frame.t_ns
        chunks: list[list[tuple[int, bytes]]] = [[]]

        def put(topic: str, message: Any) -> None:
            chunks[-1].append(self._message(topic, message))

        def end_chunk() -> None:
            chunks.append([])

        for camera in self.rig.cameras:
            put(
                topics.image_topic(camera.name),
                messages.compressed_image(t, camera.name, frame.jpeg[camera.name]),
            )
        end_chunk()
        if frame.camera_labels:  # a chunk of their own: the loader's image reads skip them
            for camera, images in frame.camera_labels.items():
                for kind, png in images.items():
                    put(topics.camera_label_topic(camera, kind), messages.png_image(t, camera, png))
            end_chunk()
        put(topics.LIDAR, messages.lidar_cloud(t, self.rig.lidar.name, frame.lidar))
        for radar in self.rig.radars:
            put(
                topics.radar_topic(radar.name),
                messages.radar_cloud(t, radar.name, frame.radars[radar.name]),
            )
        end_chunk()
        if frame.frame == self.first_frame:
            put(topics.MAP, messages.map_scene(t, self.intersection_map))
        for camera in self.rig.cameras:
            put(topics.camera_info_topic(camera.name), messages.camera_calibration(t, camera))
        for camera in self.rig.cameras:
            put(
                topics.exposure_topic(camera.name),
                messages.camera_exposure(t, camera.name, frame.exposures[camera.name]),
            )
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
        return EncodedFrame(frame.frame, int(t), tuple(finish_chunk(c, int(t)) for c in chunks))


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
        first_frame: int = 0,
        sensor_every: int = 1,
    ) -> None:
        self.path, self.partial = path, partial_path(path)
        self.sensor_every = sensor_every  # sensors at every n-th frame (`collect --sensor-hz`)
        self.encoder = FrameEncoder(
            scenario, intersection_map, rig, motion, first_frame, label_kinds(camera_labels)
        )
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.partial, "wb")
        self._container = McapContainer(
            self._file, self.encoder.channels, f"drivee2e-data {__version__}"
        )
        self._container.add_metadata(
            topics.SCENARIO_METADATA,
            {"meta": json.dumps(store.meta_document(scenario), sort_keys=True)},
        )
        self._container.add_metadata(topics.RIG_METADATA, {"rig": json.dumps(rig_document(rig))})
        self._container.add_metadata(
            topics.COLLECTION_METADATA, {"drivee2e_version": __version__, **collection}
        )
        if camera_labels:
            self._container.add_metadata(topics.CAMERA_LABELS_METADATA, camera_labels)
        self.t_ns: list[int] = []  # of the frames written
        self.first_frame = first_frame
        self._writeback = Writeback(self._file)
        self._owns_file = True  # `abort` deletes it (not a resumed head: `resume`)

    @classmethod
    def resume(
        cls,
        head: Path,
        path: Path,
        state: dict,
        scenario: Scenario,
        intersection_map: IntersectionMap,
        rig: Rig,
        motion: EgoMotion,
        camera_labels: dict[str, str] | None = None,
        sensor_every: int = 1,
    ) -> LogWriter:
        """Continue the log whose head another writer left at `head` (`suspend`, which gave
        `state`); anything after the head's end (an earlier resume that did not finish) is cut
        off. `finish` then moves the file to `path`; `abort` leaves the head as it was made
        to be resumed again."""
        writer = cls.__new__(cls)
        writer.path, writer.partial = path, head
        writer.sensor_every = sensor_every
        writer.first_frame = state["first_frame"]
        writer.encoder = FrameEncoder(
            scenario, intersection_map, rig, motion, writer.first_frame, label_kinds(camera_labels)
        )
        writer._file = open(head, "r+b")
        writer._file.truncate(state["data_end"])
        writer._file.seek(state["data_end"])
        writer._container = McapContainer.resumed(
            writer._file, writer.encoder.channels, state["container"]
        )
        writer.t_ns = list(state["t_ns"])
        writer._writeback = Writeback(writer._file)
        writer._owns_file = False
        return writer

    def write(self, frame: SensorFrame | StateFrame) -> None:
        """All topics of one frame, each with log time and publish time = the frame's time."""
        self.write_encoded(self.encoder.encode(frame))

    def write_encoded(self, encoded: EncodedFrame) -> None:
        """Write a frame `encode` made (here or in another process, with the same channels);
        frames in order."""
        expected = self.first_frame + len(self.t_ns)
        if encoded.frame != expected:
            raise ValueError(
                f"{self.path}: frame {encoded.frame} written where frame {expected} was due"
            )
        for chunk in encoded.chunks:
            self._container.add_chunk(chunk)
        self.t_ns.append(encoded.t_ns)
        self._writeback.written()

    def finish(self) -> None:
        """The frame list, index and footer, flushed to disk, then the rename that makes the
        log final."""
        self._container.add_metadata(
            topics.FRAMES_METADATA,
            {
                "first_frame": str(self.first_frame),
                "count": str(len(self.t_ns)),
                "sensor_every": str(self.sensor_every),
                "t_ns": json.dumps(self.t_ns),
            },
        )
        self._container.finish()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        os.replace(self.partial, self.path)

    def suspend(self, head: Path) -> dict:
        """Stop with the log unfinished: what was written (the log's head: every record up to
        the last frame's chunks, no summary) flushed to disk and moved to `head`; returns the
        state `resume` continues from (JSON-ready)."""
        state = {
            "data_end": self._file.tell(),
            "first_frame": self.first_frame,
            "t_ns": self.t_ns,
            "container": self._container.state(),
        }
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        os.replace(self.partial, head)
        return state

    def abort(self) -> None:
        self._file.close()
        if self._owns_file:
            self.partial.unlink(missing_ok=True)

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, exc_type: object, *rest: object) -> None:
        if exc_type is None:
            self.finish()
        else:
            self.abort()
