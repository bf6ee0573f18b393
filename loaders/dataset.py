"""`DriveE2EDataset`: a torch Dataset over a data root's MCAP logs, one sample per logged frame
of the clips of one split, with the field names nuScenes-trained planners (VAD, UniAD) read.

Logs are opened lazily in the process that reads them (a DataLoader worker opens its own), and
each clip's labels are read once per process; a sample then reads only its frame's image chunk
(and, when asked, its LiDAR/radar chunk). See docs/loaders.md for every field, its shape,
dtype and frame.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow.parquet as pq
import torch
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from google.protobuf.message import DecodeError
from numpy.typing import NDArray
from torch.utils.data import Dataset

from drivee2e_data import splits, store
from drivee2e_data.errors import DriveE2EError, LogFormatError
from drivee2e_data.loaders import sample as labels
from drivee2e_data.loaders.clip import CLASSES, ClipLabels, read_clip
from drivee2e_data.loaders.images import decode_cpu
from drivee2e_data.loaders.map_labels import (
    DEFAULT_PATCH_M,
    DEFAULT_POINTS,
    MapElements,
    bev_segmentation,
    map_elements,
    map_labels,
)
from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.sensors.camera_labels import LABEL_KINDS, decode_png

LOGS_FOLDER = "logs"
INDEX_NAME = "index.parquet"
DECODE_MODES = ("cpu", "none")
MAX_OPEN_LOGS = 32  # per process; older readers are closed
# which sample fields have one row per annotated box (padded by `collate`)
BOX_FIELDS = (
    "gt_boxes",
    "gt_labels",
    "gt_names",
    "instance_ids",
    "num_lidar_pts",
    "visibility",
    "gt_agent_fut_trajs",
    "gt_agent_fut_masks",
    "gt_agent_fut_yaw",
    "gt_agent_fut_boxes",
)
MAP_FIELDS = ("gt_map_pts", "gt_map_labels")  # one row per map polyline (padded by `collate`)


class DriveE2EDataset(Dataset):
    """Samples of one split (`train`, `val`, `test`, or `all`) of a data root.

    Args:
        root: the data root (`logs/*.mcap`, `logs/index.parquet`, `splits/`).
        split: which split of the manifest to serve.
        split_name: the manifest `root/splits/<split_name>.csv`, or a path ending in .csv.
        cameras: camera names, in the order `img` stacks them; () for no images.
        image_size: (width, height) to decode to; None for the logged size.
        decode: "cpu" decodes with OpenCV in the worker; "none" returns the JPEG bytes
            (`img_jpeg`) for `decode_batch` on the GPU.
        with_lidar, with_radar: add `points` (P, 5) / `radar_points` (R, 7), LiDAR frame.
        queue_length: frames per sample for temporal models, oldest first, `queue_stride_frames`
            10 Hz frames apart (a multiple of a log's sensor interval); per-frame fields then
            gain a leading queue dimension.
        history_s, future_s: the ego's and agents' trajectory horizons at 2 Hz.
        frame_stride: serve the sensor frames `frame_stride` 10 Hz frames apart (5 gives
            nuScenes' 2 Hz keyframes, from a 10 Hz log and from a `--sensor-hz 2` log alike).
        with_map: add the vector map labels `gt_map_pts` (K, map_points, 2) and
            `gt_map_labels` (K,) in the LiDAR frame, inside a patch of `map_patch_m` (along x,
            along y); needs the data root's `maps/<map_id>.json`.
        bev_seg: (size in pixels, metres per pixel) to add `gt_bev_seg` (3, size, size) uint8
            masks around the LiDAR: drivable area, lane lines, pedestrian crossings.
        camera_labels: some of ("depth", "semantic", "instance") from logs collected with
            `--camera-labels`: `cam_depth` (K, H, W) float32 metres (0: no hit),
            `cam_semantic` (K, H, W) uint8 (classes `SEMANTIC_CLASSES`), `cam_instance`
            (K, H, W) int64 (0: no agent, k: `cam_instance_ids[k - 1]`), resized nearest to
            the images' size.
    """

    def __init__(
        self,
        root: str | Path,
        split: str = "train",
        split_name: str = "default",
        cameras: Sequence[str] | None = topics.CAMERAS,
        image_size: tuple[int, int] | None = None,
        decode: str = "cpu",
        with_lidar: bool = False,
        with_radar: bool = False,
        queue_length: int = 1,
        queue_stride_frames: int = 5,
        history_s: float = 2.0,
        future_s: float = 3.0,
        frame_stride: int = 1,
        with_map: bool = True,
        map_patch_m: tuple[float, float] = DEFAULT_PATCH_M,
        map_points: int = DEFAULT_POINTS,
        bev_seg: tuple[int, float] | None = None,
        camera_labels: Sequence[str] = (),
    ) -> None:
        self.root = Path(root)
        if decode not in DECODE_MODES:
            raise ValueError(f"decode={decode!r}: expected one of {', '.join(DECODE_MODES)}")
        if queue_length < 1 or queue_stride_frames < 1 or frame_stride < 1:
            raise ValueError("queue_length, queue_stride_frames and frame_stride must be >= 1")
        self.split, self.decode = split, decode
        self.cameras = tuple(topics.CAMERAS if cameras is None else cameras)
        self.image_size = None if image_size is None else (int(image_size[0]), int(image_size[1]))
        self.with_lidar, self.with_radar = with_lidar, with_radar
        self.queue_length, self.queue_stride_frames = queue_length, queue_stride_frames
        self.horizons = labels.Horizons.of(history_s, future_s)
        self.with_map, self.map_patch_m, self.map_points = with_map, map_patch_m, map_points
        self.bev_seg = bev_seg
        self.camera_labels = tuple(camera_labels)
        unknown = [k for k in self.camera_labels if k not in LABEL_KINDS]
        if unknown:
            raise ValueError(
                f"camera_labels: {unknown[0]!r} is not one of {', '.join(LABEL_KINDS)}"
            )
        if self.camera_labels and not self.cameras:
            raise ValueError("camera_labels need cameras")
        if bev_seg is not None and not with_map:
            raise ValueError("bev_seg rasterises the map: it needs with_map=True")
        if split != "all" and split not in splits.SPLITS:
            raise ValueError(f"split {split!r}: expected one of {', '.join(splits.SPLITS)} or all")
        self.manifest = splits.split_path(self.root, split_name)
        rows = splits.read_manifest(self.manifest)
        chosen = [r for r in rows if split == "all" or r.split == split]
        self.categories = {r.scenario_id: r.category for r in rows}
        self.samples = self._index(chosen, frame_stride)
        self._pid = -1
        self._logs: OrderedDict[str, LogReader] = OrderedDict()
        self._clips: dict[str, ClipLabels] = {}
        self._maps: dict[str, MapElements] = {}

    # ------------------------------------------------------------------ building the index

    def _index(self, chosen: list[splits.ClipRow], frame_stride: int) -> list[tuple[str, int]]:
        index_path = self.root / LOGS_FOLDER / INDEX_NAME
        if not index_path.is_file():
            raise DriveE2EError(f"{index_path}: no frame index; run drivee2e collect {self.root}")
        try:
            # the file itself and plain lists: `pq.read_table` and `to_pydict` import pandas
            # wherever it is installed (0.4-0.6 s before the first sample)
            with pq.ParquetFile(index_path) as index:
                table = index.read(columns=["scenario_id", "frame"])
            scenario_ids = table.column("scenario_id").to_pylist()
            frame_numbers = table.column("frame").to_pylist()
        except Exception as error:  # pyarrow raises several types for a damaged file
            raise DriveE2EError(f"{index_path}: not a readable frame index ({error})") from None
        frames: dict[str, list[int]] = {}
        for scenario_id, frame in zip(scenario_ids, frame_numbers, strict=True):
            frames.setdefault(scenario_id, []).append(int(frame))
        self.log_info: dict[str, dict[str, Any]] = {}
        samples = []
        for row in chosen:
            path = self.log_path(row.scenario_id)
            if row.scenario_id not in frames or not path.is_file():
                raise DriveE2EError(
                    f"{self.manifest}: clip {row.scenario_id!r} ({row.split}) has no collected "
                    f"log; expected {path} (run drivee2e collect, or split the clips you have)"
                )
            with LogReader(path) as log:  # a truncated log fails here, naming its file
                self.log_info[row.scenario_id] = self._check_log(log)
                first = log.first_frame
            map_file = store.map_path(self.root, self.log_info[row.scenario_id]["map_id"])
            if self.with_map and not map_file.is_file():
                raise DriveE2EError(
                    f"{map_file}: the map of clip {row.scenario_id!r} is missing (map labels "
                    "need it; pass with_map=False to go without)"
                )
            # strides count 10 Hz frames whatever the log's sensor rate: the same seconds apart
            clip_frames = sorted(frames[row.scenario_id])
            samples.extend(
                (row.scenario_id, f) for f in clip_frames if (f - first) % frame_stride == 0
            )
        return samples

    def _check_log(self, log: LogReader) -> dict[str, Any]:
        if self.queue_length > 1 and self.queue_stride_frames % log.sensor_every:
            rate = topics.FRAME_RATE_HZ // log.sensor_every
            raise DriveE2EError(
                f"{log.path}: sensor data at every {log.sensor_every}th frame (collected at "
                f"{rate} Hz); queue_stride_frames={self.queue_stride_frames} must be a multiple "
                "of it"
            )
        missing = [c for c in self.cameras if c not in log.rig["cameras"]]
        if missing:
            raise DriveE2EError(
                f"{log.path}: camera {missing[0]} was not collected (the log has "
                f"{', '.join(log.cameras)})"
            )
        absent = [k for k in self.camera_labels if k not in log.camera_label_kinds]
        if absent:
            raise DriveE2EError(
                f"{log.path}: camera label {absent[0]!r} was not collected (collect with "
                "--camera-labels depth,semantic,instance)"
            )
        lidar_to_ego = log.lidar_to_ego
        cameras = {}
        for name in self.cameras:
            calibration = log.rig["cameras"][name]
            full = (int(calibration["width"]), int(calibration["height"]))
            size = self.image_size or full
            scale = np.diag([size[0] / full[0], size[1] / full[1], 1.0])
            intrinsic = scale @ np.array(calibration["intrinsic"])
            camera_to_ego = np.array(calibration["sensor_to_ego"])
            cameras[name] = {
                "full_size": full,
                "intrinsic": intrinsic,
                "cam2ego": camera_to_ego,
                "lidar2img": labels.camera_matrices(intrinsic, camera_to_ego, lidar_to_ego),
            }
        radars = {
            name: np.array(value["sensor_to_ego"]) for name, value in log.rig["radars"].items()
        }
        return {
            "lidar2ego": lidar_to_ego,
            "cameras": cameras,
            "radars": radars,
            "map_id": str(log.scenario_meta["map_id"]),
            # parsed once per log: a sample's instance values index these
            "instance_track_ids": log.camera_label_info.get("instance_track_ids", ()),
        }

    def log_path(self, scenario_id: str) -> Path:
        return self.root / LOGS_FOLDER / f"{scenario_id}.mcap"

    def __len__(self) -> int:
        return len(self.samples)

    # ------------------------------------------------------------------ per-process readers

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_logs"], state["_clips"], state["_maps"], state["_pid"] = OrderedDict(), {}, {}, -1
        return state

    def _open(self, scenario_id: str) -> tuple[LogReader, ClipLabels]:
        if self._pid != os.getpid():  # a forked worker: the parent's open files are not ours
            self._pid, self._logs, self._clips, self._maps = os.getpid(), OrderedDict(), {}, {}
        log = self._logs.get(scenario_id)
        if log is None:
            log = LogReader(self.log_path(scenario_id))
            self._logs[scenario_id] = log
            if len(self._logs) > MAX_OPEN_LOGS:
                self._logs.popitem(last=False)[1].close()
        else:
            self._logs.move_to_end(scenario_id)
        if scenario_id not in self._clips:
            self._clips[scenario_id] = read_clip(log)
        return log, self._clips[scenario_id]

    def map_elements(self, map_id: str) -> MapElements:
        """A map's labelled polylines (read and derived once per process)."""
        if map_id not in self._maps:
            self._maps[map_id] = map_elements(store.read_map(self.root, map_id))
        return self._maps[map_id]

    def clip_labels(self, scenario_id: str) -> ClipLabels:
        """The labels of one clip of this dataset (read once per process)."""
        return self._open(scenario_id)[1]

    # ------------------------------------------------------------------ samples

    def __getitem__(self, index: int) -> dict[str, Any]:
        scenario_id, frame = self.samples[index]
        log, clip = self._open(scenario_id)
        info = self.log_info[scenario_id]
        row = clip.index(frame)
        sample = self._labels(clip, row, info)
        sample.update(scene_token=scenario_id, sample_idx=f"{scenario_id}-{frame:05d}")
        sample["category"] = self.categories.get(scenario_id, splits.UNLABELLED)
        rows = [
            max(0, row - self.queue_stride_frames * (self.queue_length - 1 - q))
            for q in range(self.queue_length)
        ]
        per_frame = [self._frame(log, clip, r, info) for r in rows]
        if self.queue_length == 1:
            sample.update(per_frame[0])
        else:
            for key in per_frame[0]:
                values = [f[key] for f in per_frame]
                if torch.is_tensor(values[0]):
                    sample[key] = torch.stack(values)
                elif isinstance(values[0], (int, float)):
                    sample[key] = scalar_tensor(values)
                else:
                    sample[key] = values
            queue_valid = [
                row - self.queue_stride_frames * (self.queue_length - 1 - q) >= 0
                for q in range(self.queue_length)
            ]
            sample["queue_valid"] = torch.tensor(queue_valid)
        return sample

    def _labels(self, clip: ClipLabels, row: int, info: dict[str, Any]) -> dict[str, Any]:
        lidar_to_world = labels.ego_to_world(clip, row) @ info["lidar2ego"]
        boxes = clip.frame_boxes(row)
        history, history_mask = labels.ego_trajectory(clip, row, self.horizons.history_steps, -1)
        future, future_mask = labels.ego_trajectory(clip, row, self.horizons.future_steps, +1)
        agents = labels.agent_futures(clip, row, self.horizons.future_steps, lidar_to_world)
        light = np.zeros(4, np.float32)
        light[clip.ego_light[row]] = 1.0
        result = self._map_labels(info, lidar_to_world) if self.with_map else {}
        return result | {
            "gt_boxes": _f32(labels.box_array(boxes, lidar_to_world)),
            "gt_labels": torch.from_numpy(boxes.labels.copy()),
            "gt_names": [CLASSES[k] for k in boxes.labels],
            "instance_ids": list(boxes.instance_ids),
            "num_lidar_pts": torch.from_numpy(boxes.num_lidar_points.copy()),
            "visibility": torch.from_numpy(boxes.visibility.copy()),
            "gt_ego_his_trajs": _f32(history),
            "gt_ego_his_masks": torch.from_numpy(history_mask),
            "gt_ego_fut_trajs": _f32(future),
            "gt_ego_fut_masks": torch.from_numpy(future_mask),
            "gt_ego_fut_cmd": torch.from_numpy(labels.command_one_hot(clip.ego_command[row])),
            "ego_status": _f32(labels.ego_status(clip, row)),
            "ego_size": _f32(clip.ego_size_m),
            "ego_rear_axle_to_centre": torch.tensor(
                clip.ego_rear_axle_to_centre_m, dtype=torch.float32
            ),
            "gt_agent_fut_trajs": _f32(agents["gt_agent_fut_trajs"]),
            "gt_agent_fut_masks": torch.from_numpy(agents["gt_agent_fut_masks"]),
            "gt_agent_fut_yaw": _f32(agents["gt_agent_fut_yaw"]),
            "gt_agent_fut_boxes": _f32(agents["gt_agent_fut_boxes"]),
            "traffic_light_state": torch.from_numpy(light),
            "target_point": _f32(labels.target_point(clip, row)),
            "frame_idx": int(clip.first_frame + row),
        }

    def _map_labels(
        self, info: dict[str, Any], lidar_to_world: NDArray[np.float64]
    ) -> dict[str, Any]:
        elements = self.map_elements(info["map_id"])
        points, classes = map_labels(elements, lidar_to_world, self.map_patch_m, self.map_points)
        result = {"gt_map_pts": _f32(points), "gt_map_labels": torch.from_numpy(classes)}
        if self.bev_seg is not None:
            size_px, resolution_m = self.bev_seg
            layers = bev_segmentation(elements, lidar_to_world, int(size_px), float(resolution_m))
            result["gt_bev_seg"] = torch.from_numpy(layers)
        return result

    def _frame(
        self, log: LogReader, clip: ClipLabels, row: int, info: dict[str, Any]
    ) -> dict[str, Any]:
        """What a temporal model takes per queued frame: images, poses, CAN bus, time."""
        ego_to_world = labels.ego_to_world(clip, row)
        frame = clip.first_frame + row
        cameras = info["cameras"]
        result: dict[str, Any] = {
            "ego2global": torch.from_numpy(ego_to_world),
            "lidar2ego": torch.from_numpy(info["lidar2ego"].copy()),
            "can_bus": torch.from_numpy(labels.can_bus(clip, row)),
            "timestamp": float(clip.t_ns[row]) * 1e-9,
            "timestamp_ns": int(clip.t_ns[row]),
        }
        if self.cameras:
            result["cam_intrinsic"] = _f32(
                np.stack([cameras[c]["intrinsic"] for c in self.cameras])
            )
            result["cam2ego"] = _f32(np.stack([cameras[c]["cam2ego"] for c in self.cameras]))
            result["lidar2img"] = _f32(np.stack([cameras[c]["lidar2img"] for c in self.cameras]))
            jpegs = self.jpegs(log, clip.scenario_id, frame)
            if self.decode == "none":
                result["img_jpeg"] = [
                    torch.frombuffer(bytearray(j), dtype=torch.uint8) for j in jpegs
                ]
            else:
                result["img"] = torch.from_numpy(
                    np.stack(
                        [
                            decode_cpu(j, cameras[c]["full_size"], self.image_size)
                            for c, j in zip(self.cameras, jpegs, strict=True)
                        ]
                    )
                )
        if self.camera_labels:
            result.update(self._camera_labels(log, frame, info))
        if self.with_lidar:
            (cloud,) = self._read(log, frame, [topics.LIDAR], PointCloud)
            rows = cloud_rows(cloud)
            points = np.column_stack(
                [rows["x"], rows["y"], rows["z"], rows["intensity"], rows["ring"]]
            )
            result["points"] = torch.from_numpy(points.astype(np.float32))
        if self.with_radar:
            result["radar_points"] = torch.from_numpy(self._radar(log, frame, info))
        return result

    def _camera_labels(self, log: LogReader, frame: int, info: dict[str, Any]) -> dict[str, Any]:
        """The frame's dense labels per camera, resized nearest to the images' size."""
        cameras = info["cameras"]
        topic_names = [
            topics.camera_label_topic(c, k) for c in self.cameras for k in self.camera_labels
        ]
        images = iter(self._read(log, frame, topic_names, CompressedImage))
        stacks: dict[str, list[NDArray]] = {k: [] for k in self.camera_labels}
        for camera in self.cameras:
            size = self.image_size or cameras[camera]["full_size"]
            for kind in self.camera_labels:
                label = decode_png(next(images).data)
                if (label.shape[1], label.shape[0]) != tuple(size):
                    label = cv2.resize(label, tuple(size), interpolation=cv2.INTER_NEAREST)
                stacks[kind].append(label)
        result: dict[str, Any] = {}
        if "depth" in stacks:
            result["cam_depth"] = torch.from_numpy(
                np.stack(stacks["depth"]).astype(np.float32) / 1000
            )
        if "semantic" in stacks:
            result["cam_semantic"] = torch.from_numpy(np.stack(stacks["semantic"]))
        if "instance" in stacks:
            result["cam_instance"] = torch.from_numpy(np.stack(stacks["instance"]).astype(np.int64))
            result["cam_instance_ids"] = list(info["instance_track_ids"])
        return result

    def jpegs(self, log: LogReader, scenario_id: str, frame: int) -> list[bytes]:
        """The frame's JPEG bytes in camera order (one chunk read from the log)."""
        images = self._read(
            log, frame, [topics.image_topic(c) for c in self.cameras], CompressedImage
        )
        return [image.data for image in images]

    def _read(self, log: LogReader, frame: int, topic_names: list[str], kind: Any) -> list[Any]:
        """The frame's messages of these topics, parsed as `kind` (a protobuf class)."""
        raw = log.frame_raw(frame, topic_names)
        missing = [t for t in topic_names if t not in raw]
        if missing:
            raise LogFormatError(f"{log.path}: topic {missing[0]} has no message at frame {frame}")
        try:
            return [kind.FromString(raw[t]) for t in topic_names]
        except DecodeError as error:
            raise LogFormatError(
                f"{log.path}: frame {frame}: undecodable message ({error})"
            ) from None

    def _radar(self, log: LogReader, frame: int, info: dict[str, Any]) -> NDArray[np.float32]:
        """(R, 7) x, y, z, vx, vy, rcs, radar index (in `topics.RADARS`), LiDAR frame."""
        names = [n for n in topics.RADARS if n in info["radars"]]
        clouds = self._read(log, frame, [topics.radar_topic(n) for n in names], PointCloud)
        ego_to_lidar = np.linalg.inv(info["lidar2ego"])
        parts = []
        for name, cloud in zip(names, clouds, strict=True):
            rows = cloud_rows(cloud)
            radar_to_lidar = ego_to_lidar @ info["radars"][name]
            xyz = np.column_stack([rows["x"], rows["y"], rows["z"]]) @ radar_to_lidar[:3, :3].T
            xyz += radar_to_lidar[:3, 3]
            velocity = np.column_stack([rows["vx"], rows["vy"], np.zeros(len(rows))])
            velocity = velocity @ radar_to_lidar[:3, :3].T
            index = np.full(len(rows), topics.RADARS.index(name))
            parts.append(np.column_stack([xyz, velocity[:, :2], rows["rcs"], index]))
        return np.concatenate(parts).astype(np.float32) if parts else np.zeros((0, 7), np.float32)


_FIELD_TYPES = {1: "u1", 7: "<f4", 8: "<f8"}  # foxglove PackedElementField numeric types used


def cloud_rows(cloud: Any) -> NDArray:
    """A foxglove PointCloud's points as a structured array, fields as the message lays them."""
    fields = {f.name: (np.dtype(_FIELD_TYPES[f.type]), f.offset) for f in cloud.fields}
    dtype = np.dtype(
        {
            "names": list(fields),
            "formats": [v[0] for v in fields.values()],
            "offsets": [v[1] for v in fields.values()],
            "itemsize": cloud.point_stride,
        }
    )
    return np.frombuffer(cloud.data, dtype)


def scalar_tensor(values: list) -> torch.Tensor:
    """Python numbers as a tensor: int64, or float64 (timestamps in seconds since 1970 need
    more than float32's seven digits)."""
    return torch.tensor(
        values, dtype=torch.float64 if isinstance(values[0], float) else torch.int64
    )


def _f32(array: NDArray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(array, np.float32))
