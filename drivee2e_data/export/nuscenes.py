"""Export collected clips to the nuScenes table layout, so the official `nuscenes-devkit`
loads them with `NuScenes(version=..., dataroot=...)`.

One clip is one nuScenes scene (and one log); every `keyframe_every`-th logged frame is a
sample with six camera JPEGs (copied from the log, not re-encoded) and the LiDAR sweep as
`.pcd.bin` (float32 x, y, z, intensity 0-1, ring). Each intersection map is a map record with a
drivable-area mask at 0.1 m. Frames and classes as `export/common.py` states.

The export is built in a hidden sibling folder and renamed into place when complete.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import shapely

from drivee2e_data import splits, store
from drivee2e_data.export import common
from drivee2e_data.loaders.clip import CLASSES, ClipLabels, read_clip
from drivee2e_data.loaders.dataset import cloud_rows
from drivee2e_data.loaders.map_labels import map_elements
from drivee2e_data.loaders.sample import ego_to_world
from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader

TABLES = (
    "category",
    "attribute",
    "visibility",
    "instance",
    "sensor",
    "calibrated_sensor",
    "ego_pose",
    "log",
    "scene",
    "sample",
    "sample_data",
    "sample_annotation",
    "map",
)
ATTRIBUTES = (
    "vehicle.moving",
    "vehicle.stopped",
    "pedestrian.moving",
    "pedestrian.standing",
    "cycle.with_rider",
)
VISIBILITY_LEVELS = {"1": "v0-40", "2": "v40-60", "3": "v60-80", "4": "v80-100"}


@dataclass
class ExportSummary:
    out: Path
    scenes: int = 0
    samples: int = 0
    annotations: int = 0


def clips_for(root: Path, split: str, split_name: str) -> list[str]:
    """The clips of a split (`all`: the whole manifest, or every log without a manifest)."""
    manifest = splits.split_path(root, split_name)
    if split == "all" and not manifest.is_file():
        return sorted(p.stem for p in (Path(root) / "logs").glob("*.mcap"))
    rows = splits.read_manifest(manifest)
    return [r.scenario_id for r in rows if split == "all" or r.split == split]


def export_nuscenes(
    root: Path,
    out: Path,
    version: str = "v1.0-drivee2e",
    split: str = "all",
    split_name: str = "default",
    keyframe_every: int = 5,
    on_sample: Callable[[int], None] | None = None,
) -> ExportSummary:
    """Write the nuScenes layout of the split's clips under `out` (which must not exist)."""
    root, out = Path(root), Path(out)
    common.check_out(out)
    scenario_ids = clips_for(root, split, split_name)
    building = out.with_name(f".{out.name}.{os.getpid()}.partial")
    shutil.rmtree(building, ignore_errors=True)
    try:
        tables = _Tables(building, version)
        summary = ExportSummary(out)
        for scenario_id in scenario_ids:
            with LogReader(root / "logs" / f"{scenario_id}.mcap") as log:
                tables.add_clip(root, log, read_clip(log), keyframe_every, on_sample)
        tables.write()
        summary.scenes, summary.samples = (
            len(tables.records["scene"]),
            len(tables.records["sample"]),
        )
        summary.annotations = len(tables.records["sample_annotation"])
        os.replace(building, out)
    except BaseException:
        shutil.rmtree(building, ignore_errors=True)
        raise
    return summary


class _Tables:
    def __init__(self, folder: Path, version: str) -> None:
        self.folder, self.version = folder, version
        self.records: dict[str, list[dict[str, Any]]] = {name: [] for name in TABLES}
        self.maps: dict[str, dict[str, Any]] = {}
        self.instances: dict[str, dict[str, Any]] = {}
        # records by token, to link prev/next as later frames arrive
        self._by_token: dict[str, dict[str, Any]] = {}
        self._annotations: dict[str, dict[str, Any]] = {}
        used = sorted({common.NUSCENES_CATEGORY[c][:2] for c in CLASSES}, key=lambda c: c[1])
        for name, index in used:
            folded = [c for c in CLASSES if common.NUSCENES_CATEGORY[c][0] == name]
            self.records["category"].append(
                {
                    "token": common.token("category", name),
                    "name": name,
                    "description": f"drivee2e classes: {', '.join(folded)}",
                    "index": index,
                }
            )
        for name in ATTRIBUTES:
            self.records["attribute"].append(
                {"token": common.token("attribute", name), "name": name, "description": name}
            )
        for level, name in VISIBILITY_LEVELS.items():
            self.records["visibility"].append(
                {
                    "token": level,
                    "level": name,
                    "description": f"visibility of whole object is {name[1:]}%",
                }
            )
        for channel in (*topics.CAMERAS, "LIDAR_TOP"):
            self.records["sensor"].append(
                {
                    "token": common.token("sensor", channel),
                    "channel": channel,
                    "modality": "lidar" if channel == "LIDAR_TOP" else "camera",
                }
            )

    def add_clip(
        self,
        root: Path,
        log: LogReader,
        clip: ClipLabels,
        keyframe_every: int,
        on_sample: Callable[[int], None] | None,
    ) -> None:
        scenario_id, map_id = clip.scenario_id, str(log.scenario_meta["map_id"])
        intersection_map = store.read_map(root, map_id)
        offset = common.global_offset(intersection_map)
        log_token = common.token("log", scenario_id)
        self._add_map(map_id, intersection_map, offset, log_token)
        start = log.scenario_meta.get("conditions", {}).get("start_time_utc", "")
        self.records["log"].append(
            {
                "token": log_token,
                "logfile": scenario_id,
                "vehicle": "drivee2e-ego",
                "date_captured": start[:10],
                "location": map_id,
                "drivee2e_global_offset_m": offset.tolist(),
            }
        )
        calibration = self._add_calibration(scenario_id, log)
        frames = common.keyframes(
            clip.first_frame, clip.num_frames, keyframe_every, clip.sensor_every
        )
        scene_token = common.token("scene", scenario_id)
        sample_tokens = [common.token("sample", scenario_id, f) for f in frames]
        previous_data: dict[str, str] = {}
        for k, frame in enumerate(frames):
            row = clip.index(frame)
            t_ns = int(clip.t_ns[row])
            pose = ego_to_world(clip, row)
            pose[:3, 3] += offset
            pose_token = common.token("ego_pose", scenario_id, frame)
            self.records["ego_pose"].append(
                {
                    "token": pose_token,
                    "timestamp": t_ns // 1000,
                    "rotation": common.quaternion_list(pose[:3, :3]),
                    "translation": pose[:3, 3].tolist(),
                }
            )
            self.records["sample"].append(
                {
                    "token": sample_tokens[k],
                    "timestamp": t_ns // 1000,
                    "prev": sample_tokens[k - 1] if k else "",
                    "next": sample_tokens[k + 1] if k + 1 < len(frames) else "",
                    "scene_token": scene_token,
                }
            )
            self._add_sensor_data(
                log,
                scenario_id,
                frame,
                t_ns,
                sample_tokens[k],
                pose_token,
                calibration,
                previous_data,
            )
            self._add_annotations(clip, row, frame, sample_tokens[k], offset)
            if on_sample is not None:
                on_sample(1)
        self.records["scene"].append(
            {
                "token": scene_token,
                "log_token": log_token,
                "nbr_samples": len(frames),
                "first_sample_token": sample_tokens[0],
                "last_sample_token": sample_tokens[-1],
                "name": scenario_id,
                "description": _describe(log.scenario_meta),
            }
        )

    def _add_map(
        self, map_id: str, intersection_map: Any, offset: np.ndarray, log_token: str
    ) -> None:
        if map_id in self.maps:
            self.maps[map_id]["log_tokens"].append(log_token)
            return
        _, high = common.map_bounds(intersection_map)
        size = np.ceil(
            (high[:2] + offset[:2] + common.MAP_MARGIN_M) / common.MAP_RESOLUTION_M
        ).astype(int)
        mask = np.zeros((size[1], size[0]), np.uint8)

        def pixels(points: np.ndarray) -> np.ndarray:
            shifted = (points[:, :2] + offset[:2]) / common.MAP_RESOLUTION_M
            return np.round(np.column_stack([shifted[:, 0], size[1] - shifted[:, 1]])).astype(
                np.int32
            )

        # the road surface as the map labels define it: one union, so overlapping lane
        # polygons (in junctions) cannot cancel out as they would filled together
        for polygon in shapely.get_parts(map_elements(intersection_map).road):
            cv2.fillPoly(mask, [pixels(np.asarray(polygon.exterior.coords))], 255)
            for hole in polygon.interiors:
                cv2.fillPoly(mask, [pixels(np.asarray(hole.coords))], 0)
        path = self.folder / common.map_file(map_id)
        path.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(path), mask)
        record = {
            "token": common.token("map", map_id),
            "log_tokens": [log_token],
            "category": "semantic_prior",
            "filename": common.map_file(map_id),
        }
        self.maps[map_id] = record
        self.records["map"].append(record)

    def _add_calibration(self, scenario_id: str, log: LogReader) -> dict[str, dict[str, Any]]:
        calibration = {}
        for channel in log.cameras:
            camera = log.rig["cameras"][channel]
            sensor_to_ego = np.array(camera["sensor_to_ego"])
            calibration[channel] = {
                "token": common.token("calibrated_sensor", scenario_id, channel),
                "sensor_token": common.token("sensor", channel),
                "translation": sensor_to_ego[:3, 3].tolist(),
                "rotation": common.quaternion_list(sensor_to_ego[:3, :3]),
                "camera_intrinsic": np.array(camera["intrinsic"]).tolist(),
                "width": int(camera["width"]),
                "height": int(camera["height"]),
            }
        lidar = common.nuscenes_lidar_to_ego(log.lidar_to_ego)
        calibration["LIDAR_TOP"] = {
            "token": common.token("calibrated_sensor", scenario_id, "LIDAR_TOP"),
            "sensor_token": common.token("sensor", "LIDAR_TOP"),
            "translation": lidar[:3, 3].tolist(),
            "rotation": common.quaternion_list(lidar[:3, :3]),
            "camera_intrinsic": [],
        }
        for record in calibration.values():
            self.records["calibrated_sensor"].append(
                {k: v for k, v in record.items() if k not in ("width", "height")}
            )
        return calibration

    def _add_sensor_data(
        self,
        log: LogReader,
        scenario_id: str,
        frame: int,
        t_ns: int,
        sample_token: str,
        pose_token: str,
        calibration: dict[str, dict[str, Any]],
        previous: dict[str, str],
    ) -> None:
        wanted = [topics.image_topic(c) for c in log.cameras] + [topics.LIDAR]
        messages = log.frame(frame, wanted)
        for channel in (*log.cameras, "LIDAR_TOP"):
            is_lidar = channel == "LIDAR_TOP"
            name = common.sample_file(scenario_id, channel, t_ns, "pcd.bin" if is_lidar else "jpg")
            path = self.folder / name
            path.parent.mkdir(parents=True, exist_ok=True)
            if is_lidar:
                rows = cloud_rows(messages[topics.LIDAR])
                xyz = (
                    np.column_stack([rows["x"], rows["y"], rows["z"]]) @ common.TO_NUSCENES_LIDAR.T
                )
                points = np.column_stack([xyz, rows["intensity"], rows["ring"]]).astype(np.float32)
                path.write_bytes(points.tobytes())
            else:
                path.write_bytes(messages[topics.image_topic(channel)].data)
            data_token = common.token("sample_data", scenario_id, frame, channel)
            record = {
                "token": data_token,
                "sample_token": sample_token,
                "ego_pose_token": pose_token,
                "calibrated_sensor_token": calibration[channel]["token"],
                "timestamp": t_ns // 1000,
                "fileformat": "pcd" if is_lidar else "jpg",
                "is_key_frame": True,
                "height": 0 if is_lidar else calibration[channel]["height"],
                "width": 0 if is_lidar else calibration[channel]["width"],
                "filename": name,
                "prev": previous.get(channel, ""),
                "next": "",
            }
            if channel in previous:
                self._by_token[previous[channel]]["next"] = data_token
            previous[channel] = data_token
            self.records["sample_data"].append(record)
            self._by_token[data_token] = record

    def _add_annotations(
        self, clip: ClipLabels, row: int, frame: int, sample_token: str, offset: np.ndarray
    ) -> None:
        boxes = clip.frame_boxes(row)
        for k, instance_id in enumerate(boxes.instance_ids):
            class_name = CLASSES[boxes.labels[k]]
            category, _, _ = common.NUSCENES_CATEGORY[class_name]
            instance_token = common.token("instance", clip.scenario_id, instance_id)
            annotation_token = common.token(
                "sample_annotation", clip.scenario_id, frame, instance_id
            )
            length, width, height = boxes.size_m[k]
            yaw = boxes.yaw_rad[k]
            rotation = np.array(
                [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]]
            )
            speed = float(np.hypot(*boxes.velocity_mps[k]))
            record = {
                "token": annotation_token,
                "sample_token": sample_token,
                "instance_token": instance_token,
                "visibility_token": str(max(1, int(boxes.visibility[k]))),
                "attribute_tokens": [
                    common.token("attribute", common.attribute(class_name, speed))
                ],
                "translation": (boxes.centre_m[k] + offset).tolist(),
                "size": [float(width), float(length), float(height)],
                "rotation": common.quaternion_list(rotation),
                "prev": "",
                "next": "",
                "num_lidar_pts": int(boxes.num_lidar_points[k]),
                "num_radar_pts": int(boxes.num_radar_points[k]),
                "drivee2e_class": class_name,
                "drivee2e_visibility": int(boxes.visibility[k]),
            }
            instance = self.instances.get(instance_token)
            if instance is None:
                instance = {
                    "token": instance_token,
                    "category_token": common.token("category", category),
                    "nbr_annotations": 0,
                    "first_annotation_token": annotation_token,
                    "last_annotation_token": annotation_token,
                }
                self.instances[instance_token] = instance
                self.records["instance"].append(instance)
            else:
                last = self._annotations[instance["last_annotation_token"]]
                last["next"], record["prev"] = annotation_token, last["token"]
                instance["last_annotation_token"] = annotation_token
            instance["nbr_annotations"] += 1
            self._annotations[annotation_token] = record
            self.records["sample_annotation"].append(record)

    def write(self) -> None:
        tables = self.folder / self.version
        tables.mkdir(parents=True, exist_ok=True)
        for name, records in self.records.items():
            (tables / f"{name}.json").write_text(json.dumps(records, indent=1), encoding="utf-8")


def _describe(meta: dict[str, Any]) -> str:
    behavior = (meta.get("behavior") or {}).get("sub_scenario", "unlabelled")
    conditions = meta.get("conditions") or {}
    return f"{behavior}, {conditions.get('weather', '?')}, {conditions.get('time_of_day', '?')}; source {meta.get('source', '?')}"
