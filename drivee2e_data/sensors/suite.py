"""The whole rig for one frame: cameras (rendered, weather applied, JPEG), the LiDAR sweep,
radar returns, GNSS and IMU, the top view, and every agent's box annotation.

`SensorSuite.capture(frame)` poses the world at the logged frame with the ego at its logged
pose and returns a `SensorFrame`, plain data the log writer turns into messages. Wall time per
stage is kept in `SensorFrame.seconds` for the collection benchmark.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.scenario import SignalState, Track
from drivee2e_data.sensors import (
    annotate,
    bev,
    camera_gpu,
    camera_labels,
    lidar,
    lidar_depth,
    radar,
)
from drivee2e_data.sensors.camera import (
    CameraFrame,
    camera_exposure,
    drawn_view,
    encode_jpeg,
    render,
    with_conditions,
)
from drivee2e_data.sensors.camera_labels import DEFAULT_LABEL_SCALE
from drivee2e_data.sensors.ego_state import EgoMotion, ego_motion
from drivee2e_data.sensors.imu_gnss import enu_to_wgs84, imu
from drivee2e_data.sensors.rig import Rig, default_rig
from drivee2e_data.sim.conditions import Exposure
from drivee2e_data.sim.world import World

STAGES = ("render", "post_process", "jpeg", "labels", "lidar", "radar", "annotate", "bev")
ANNOTATION_RANGE_M = 100.0  # boxes farther from the ego than this are not annotated


LIDAR_METHODS = ("raycast", "depth")
# where a box's visible share comes from: the depth image every camera renders anyway, or the
# body mask, a second render pass per camera (the reference; camera labels need it anyway)
VISIBILITY_SOURCES = ("depth", "mask")


@dataclass(frozen=True)
class SuiteOptions:
    cameras: tuple[str, ...] | None = None  # None: all six
    image_size: tuple[int, int] | None = None  # (width, height); None: the rig's 1600x900
    jpeg_quality: int = 85
    bev_size_px: int = bev.DEFAULT_SIZE_PX
    camera_labels: tuple[str, ...] = ()  # some of camera_labels.LABEL_KINDS
    label_scale: int = DEFAULT_LABEL_SCALE
    lidar: str = "raycast"  # one of LIDAR_METHODS: ray casting, or read from depth images
    visibility: str = "depth"  # one of VISIBILITY_SOURCES
    # where camera images get their weather, resize and JPEG: "cpu" (OpenCV, the reference) or
    # "cuda" (torch and nvJPEG, camera_gpu)
    post_process: str = "cpu"


@dataclass(frozen=True)
class BoxAnnotation:
    """One agent's box at a frame, sized as the blueprint drawn for it."""

    track_id: str
    category: str
    blueprint: str
    size_m: NDArray[np.float64]  # (3,) length, width, height
    centre_world_m: NDArray[np.float64]  # (3,)
    yaw_world_rad: float
    velocity_world_mps: NDArray[np.float64]  # (2,)
    centre_ego_m: NDArray[np.float64]  # (3,)
    yaw_ego_rad: float
    velocity_ego_mps: NDArray[np.float64]  # (2,) rotated into the ego frame
    visibility: int  # nuScenes token 0-4
    visible_share: float
    cameras: tuple[str, ...]
    num_lidar_points: int
    num_radar_points: int


@dataclass(frozen=True)
class SensorFrame:
    frame: int
    t_ns: int
    ego_to_world: NDArray[np.float64]  # (4, 4)
    jpeg: dict[str, bytes]  # camera name -> JPEG bytes
    lidar: lidar.LidarSweep
    radars: dict[str, radar.RadarReturns]
    gnss_lat_lon_alt: NDArray[np.float64]  # (3,) degrees, degrees, metres
    imu_acceleration_mps2: NDArray[np.float64]  # (3,) vehicle frame
    imu_angular_velocity_radps: NDArray[np.float64]  # (3,)
    boxes: tuple[BoxAnnotation, ...]
    signals: dict[str, SignalState]
    bev_jpeg: bytes
    seconds: dict[str, float] = field(default_factory=dict)  # wall time per stage
    # camera name -> label kind -> PNG bytes (with SuiteOptions.camera_labels)
    camera_labels: dict[str, dict[str, bytes]] = field(default_factory=dict)
    # camera name -> its exposure at this frame (`conditions.exposure`), logged beside its image
    exposures: dict[str, Exposure] = field(default_factory=dict)


@dataclass(frozen=True)
class StateFrame:
    """A frame between sensor frames (`collect --sensor-hz`): where the ego is and what it
    feels, and the lights; nothing rendered. Field names as `SensorFrame`'s."""

    frame: int
    t_ns: int
    ego_to_world: NDArray[np.float64]  # (4, 4)
    gnss_lat_lon_alt: NDArray[np.float64]  # (3,)
    imu_acceleration_mps2: NDArray[np.float64]  # (3,)
    imu_angular_velocity_radps: NDArray[np.float64]  # (3,)
    signals: dict[str, SignalState]
    seconds: dict[str, float] = field(default_factory=dict)


class SensorSuite:
    """The rig mounted on the ego of the world's scenario."""

    def __init__(self, world: World, options: SuiteOptions | None = None) -> None:
        self.world, self.options = world, options or SuiteOptions()
        self.rig = configured_rig(self.options)
        scenario = world.scenario
        self.motion: EgoMotion = ego_motion(scenario)
        self.imu_acceleration, self.imu_angular_velocity = imu(scenario.ego)
        if self.options.lidar not in LIDAR_METHODS:
            raise ValueError(
                f"lidar {self.options.lidar!r}: expected one of {', '.join(LIDAR_METHODS)}"
            )
        if self.options.visibility not in VISIBILITY_SOURCES:
            raise ValueError(
                f"visibility {self.options.visibility!r}: expected one of "
                f"{', '.join(VISIBILITY_SOURCES)}"
            )
        camera_gpu.check_device(self.options.post_process)
        unknown = set(self.options.camera_labels) - set(camera_labels.LABEL_KINDS)
        if unknown:
            raise ValueError(
                f"camera label {sorted(unknown)[0]!r}: expected some of "
                f"{', '.join(camera_labels.LABEL_KINDS)}"
            )
        # instance value k + 1 is the clip's k-th track
        self.instance_index = {t.track_id: k for k, t in enumerate(scenario.tracks)}
        self.label_tables = None
        if self.options.camera_labels:
            self.label_tables = camera_labels.LabelTables.build(
                world.twin.segmentation,
                world.bodies,
                {t.track_id: t.agent_class for t in scenario.tracks},
                self.instance_index,
            )

    def capture_state(self, frame: int) -> StateFrame:
        """The frame's pose, GNSS, IMU and lights, without rendering anything."""
        scenario = self.world.scenario
        ego_to_world = self.motion.ego_to_world(frame)
        position = ego_to_world[:3, 3]
        return StateFrame(
            frame=frame,
            t_ns=int(scenario.t_ns[frame]),
            ego_to_world=ego_to_world,
            gnss_lat_lon_alt=enu_to_wgs84(position, self.world.intersection_map.origin)[0],
            imu_acceleration_mps2=self.imu_acceleration[frame],
            imu_angular_velocity_radps=self.imu_angular_velocity[frame],
            signals={s.signal_id: s.state_at(frame) for s in scenario.signals},
        )

    def capture(self, frame: int) -> SensorFrame:
        world, scenario, seconds = self.world, self.world.scenario, dict.fromkeys(STAGES, 0.0)
        ego = scenario.ego
        ego_to_world = self.motion.ego_to_world(frame)
        world.place_ego(float(ego.x_m[frame]), float(ego.y_m[frame]), ego.track_id)
        world.set_time(frame)
        views: list[CameraFrame] = []
        jpeg: dict[str, bytes] = {}
        exposures: dict[str, Exposure] = {}
        mask = self.label_tables is not None or self.options.visibility == "mask"
        labels: dict[str, dict[str, bytes]] = {}
        on_cpu = self.options.post_process == "cpu"
        with _timed(seconds, "annotate"):
            annotated = self._to_annotate(frame, ego_to_world)
            corners = np.stack([c for _, _, c in annotated]) if annotated else np.zeros((0, 8, 3))
        # box visibility reads the cameras' depth at a few pixels a box: chosen before drawing,
        # so that a GPU reads back those alone (the CUDA path finishes images from the depth)
        pixels: list[annotate.DepthPixels | None] = [None] * len(self.rig.cameras)
        for k, camera in enumerate(self.rig.cameras):
            if not mask and on_cpu:
                with _timed(seconds, "annotate"):
                    view_size = drawn_view(world, camera)
                    pixels[k] = annotate.depth_pixels(view_size, corners, ego_to_world)
            with _timed(seconds, "render"):
                depth_at = None if pixels[k] is None else pixels[k].texels
                view = render(world, camera, ego_to_world, mask=mask, depth_at=depth_at)
            with _timed(seconds, "post_process"):
                exposures[camera.name] = camera_exposure(world, view)
            if on_cpu:
                with _timed(seconds, "post_process"):
                    rgb = with_conditions(world, view, frame, exposures[camera.name])
                with _timed(seconds, "jpeg"):
                    jpeg[camera.name] = encode_jpeg(rgb, self.options.jpeg_quality)
            if self.label_tables is not None and view.mask is not None:
                with _timed(seconds, "labels"):
                    images = camera_labels.label_images(
                        view.depth_m, view.mask, self.label_tables, self.options.label_scale,
                        self.options.camera_labels, (camera.width, camera.height),
                    )  # fmt: skip
                    labels[camera.name] = {
                        kind: camera_labels.encode_png(image) for kind, image in images.items()
                    }
            views.append(view)
        if not on_cpu:  # the six images as one batch on the GPU
            with _timed(seconds, "post_process"):
                images = camera_gpu.finish(
                    world, views, frame, self.options.post_process, list(exposures.values())
                )
            with _timed(seconds, "jpeg"):
                encoded = camera_gpu.encode(images, self.options.jpeg_quality)
            jpeg = {view.camera.name: data for view, data in zip(views, encoded, strict=True)}
        with _timed(seconds, "lidar"):
            lidar_to_world = ego_to_world @ self.rig.lidar.sensor_to_ego
            if self.options.lidar == "depth":
                sweep = lidar_depth.depth_sweep(
                    world, self.rig.lidar, lidar_to_world, world.twin.paint_raster()
                )
            else:
                sweep = lidar.sweep(
                    world.client,
                    self.rig.lidar,
                    lidar_to_world,
                    world.twin.segmentation,
                    world.twin.paint_raster(),
                )
        with _timed(seconds, "radar"):
            velocity = np.array([ego.vx_mps[frame], ego.vy_mps[frame]])
            returns = {
                r.name: radar.detect(
                    r,
                    ego_to_world @ r.sensor_to_ego,
                    velocity,
                    list(scenario.tracks),
                    frame,
                    ego.track_id,
                )
                for r in self.rig.radars
            }
        with _timed(seconds, "annotate"):
            boxes = self._annotate(
                frame, ego_to_world, views, sweep, lidar_to_world, returns, annotated, pixels
            )
        with _timed(seconds, "bev"):
            # the top view shows the ego too: the GL renderer draws it from the cameras' state
            # (hidden from them, it casts its shadow there); pybullet's draw bodies where they are
            if world.gl is None:
                world.place_ego(float(ego.x_m[frame]), float(ego.y_m[frame]), None)
                world.set_time(frame)
            top = bev.top_view(world, ego_to_world, self.options.bev_size_px,
                               casters_drawn=world.gl is not None)  # fmt: skip
            bev_jpeg = encode_jpeg(top, self.options.jpeg_quality)
        state = self.capture_state(frame)
        return SensorFrame(
            frame=frame,
            t_ns=state.t_ns,
            ego_to_world=ego_to_world,
            jpeg=jpeg,
            lidar=sweep,
            radars=returns,
            gnss_lat_lon_alt=state.gnss_lat_lon_alt,
            imu_acceleration_mps2=state.imu_acceleration_mps2,
            imu_angular_velocity_radps=state.imu_angular_velocity_radps,
            boxes=boxes,
            signals=state.signals,
            bev_jpeg=bev_jpeg,
            seconds=seconds,
            camera_labels=labels,
            exposures=exposures,
        )

    def _to_annotate(
        self, frame: int, ego_to_world: NDArray[np.float64]
    ) -> list[tuple[Track, int, NDArray[np.float64]]]:
        """(track, body, corners (8, 3)) of each box the frame annotates: the agents valid at
        the frame within `ANNOTATION_RANGE_M` of the ego."""
        world, scenario = self.world, self.world.scenario
        annotated = []
        for track in scenario.tracks:
            if track.track_id == scenario.ego_id or not track.valid[frame]:
                continue
            centre_xy = np.array([track.x_m[frame], track.y_m[frame]])
            if np.hypot(*(centre_xy - ego_to_world[:2, 3])) > ANNOTATION_RANGE_M:
                continue
            blueprint = world.blueprints[track.track_id]
            corners = annotate.box_corners_3d(track, frame, blueprint.size_m)
            annotated.append((track, world.bodies[track.track_id], corners))
        return annotated

    def _annotate(
        self,
        frame: int,
        ego_to_world: NDArray[np.float64],
        views: list[CameraFrame],
        sweep: lidar.LidarSweep,
        lidar_to_world: NDArray[np.float64],
        returns: dict[str, radar.RadarReturns],
        annotated: list[tuple[Track, int, NDArray[np.float64]]],
        pixels: list[annotate.DepthPixels | None],
    ) -> tuple[BoxAnnotation, ...]:
        """The boxes of `annotated` (`_to_annotate`), each view's visible shares from the
        pixels its depth was read at (`pixels`, None: chosen here)."""
        world = self.world
        world_to_ego = np.linalg.inv(ego_to_world)
        ego_yaw = float(self.motion.yaw_rad[frame])
        bodies = [body for _, body, _ in annotated]
        hits = _returns_by_body(sweep.body, bodies)
        radar_counts: dict[str, int] = {}
        for result in returns.values():
            for track_id in result.track_ids:
                radar_counts[track_id] = radar_counts.get(track_id, 0) + 1
        # (cameras, boxes): each view tests all its boxes at once
        by_view = np.zeros((len(views), len(annotated)))
        if annotated:
            all_corners = np.stack([corners for _, _, corners in annotated])
            for k, view in enumerate(views):
                by_view[k] = annotate.visible_shares(
                    view, bodies, all_corners, ego_to_world, pixels[k]
                )
        boxes = []
        for index, (track, body, corners) in enumerate(annotated):
            centre_xy = np.array([track.x_m[frame], track.y_m[frame]])
            blueprint = world.blueprints[track.track_id]
            size = np.array(blueprint.size_m)
            shares = {view.camera.name: float(by_view[k, index]) for k, view in enumerate(views)}
            share = max(shares.values(), default=0.0)
            centre_world = np.array([*centre_xy, corners[0, 2] + 0.5 * size[2]])
            centre_ego = (world_to_ego @ np.append(centre_world, 1.0))[:3]
            velocity = np.array([track.vx_mps[frame], track.vy_mps[frame]])
            c, s = np.cos(ego_yaw), np.sin(ego_yaw)
            boxes.append(
                BoxAnnotation(
                    track_id=track.track_id,
                    category=track.agent_class.value,
                    blueprint=blueprint.name,
                    size_m=size,
                    centre_world_m=centre_world,
                    yaw_world_rad=float(track.yaw_rad[frame]),
                    velocity_world_mps=velocity,
                    centre_ego_m=centre_ego,
                    yaw_ego_rad=float(
                        np.arctan2(
                            np.sin(track.yaw_rad[frame] - ego_yaw),
                            np.cos(track.yaw_rad[frame] - ego_yaw),
                        )
                    ),
                    velocity_ego_mps=np.array(
                        [c * velocity[0] + s * velocity[1], -s * velocity[0] + c * velocity[1]]
                    ),
                    visibility=annotate.visibility_level(share),
                    visible_share=share,
                    cameras=tuple(name for name, value in shares.items() if value > 0.0),
                    num_lidar_points=_points_in_box(sweep, hits.get(body), lidar_to_world, corners),
                    num_radar_points=int(radar_counts.get(track.track_id, 0)),
                )
            )
        return tuple(boxes)


def _returns_by_body(hit_body: NDArray[np.int32], bodies: list[int]) -> dict[int, NDArray[np.intp]]:
    """The indices of the sweep's returns on each of `bodies` that has any, in sweep order.
    Only those returns are sorted: the road's and the buildings' (most of a sweep) are not."""
    if not bodies or not len(hit_body):
        return {}
    wanted = np.zeros(max(int(hit_body.max()), *bodies) + 1, dtype=bool)
    wanted[bodies] = True  # body ids, the sweep's as well as these, are >= 0
    chosen = np.flatnonzero(wanted[hit_body])
    if not len(chosen):
        return {}
    order = chosen[np.argsort(hit_body[chosen], kind="stable")]
    found, starts = np.unique(hit_body[order], return_index=True)
    ends = np.append(starts[1:], len(order))
    return {int(b): order[a:e] for b, a, e in zip(found, starts, ends, strict=True)}


# a box counts its model's returns within this much of its faces: a steered front wheel pokes a
# centimetre or two out of the box (`models.mesh.STEER_LIMIT_RAD`), and a box's points lie in it
BOX_POINT_MARGIN_M = 0.02


def _points_in_box(
    sweep: lidar.LidarSweep,
    indices: NDArray[np.intp] | None,
    lidar_to_world: NDArray[np.float64],
    corners: NDArray[np.float64],
) -> int:
    """How many of the agent's own returns (`indices` into the sweep) lie in its box, grown by
    `BOX_POINT_MARGIN_M` on every side."""
    if indices is None or not len(indices):
        return 0
    points = sweep.points_m[indices].astype(np.float64) @ lidar_to_world[:3, :3].T
    points += lidar_to_world[:3, 3]
    return annotate.points_in_box(points, corners, BOX_POINT_MARGIN_M)


def configured_rig(options: SuiteOptions) -> Rig:
    """The default rig with the options' cameras and image size."""
    rig = default_rig()
    cameras = rig.cameras
    if options.cameras is not None:
        known = {c.name for c in cameras}
        unknown = [name for name in options.cameras if name not in known]
        if unknown:
            raise ValueError(f"unknown camera {unknown[0]!r}: expected some of {', '.join(known)}")
        cameras = tuple(c for c in cameras if c.name in options.cameras)
    if options.image_size is not None:
        width, height = options.image_size
        cameras = tuple(replace(c, width=width, height=height) for c in cameras)
    return replace(rig, cameras=cameras)


@contextmanager
def _timed(seconds: dict[str, float], stage: str) -> Iterator[None]:
    start = time.perf_counter()
    yield
    seconds[stage] += time.perf_counter() - start
