"""One clip, one job: replay the clip in a pybullet world, capture the sensor suite at every
frame, write the log atomically. A job never raises for a bad clip: it returns a `JobResult`
saying why, so one clip cannot stop the others.

A worker process keeps its last world and reuses its twin when the next clip is on the same
map (building a twin takes a second or two).
"""

from __future__ import annotations

import atexit
import functools
import json
import os
import resource
import time
import traceback
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from drivee2e_data import store
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.logs import topics
from drivee2e_data.logs.writer import LogWriter
from drivee2e_data.sensors import camera_gpu
from drivee2e_data.sensors.camera_labels import DEFAULT_LABEL_SCALE, SEMANTIC_CLASSES
from drivee2e_data.sensors.suite import STAGES, SensorFrame, SensorSuite, StateFrame, SuiteOptions
from drivee2e_data.sim import gl_context, reuse
from drivee2e_data.sim.world import World, world_for

LOGS_FOLDER = "logs"
# what a job's `stage_seconds` hold: each frame's stages, writing it, and the world's set-up
# (once a job, not a frame's: it depends on how the plan cut the clip)
FRAME_STAGES = (*STAGES, "write")
JOB_STAGES = (*FRAME_STAGES, "setup")


@dataclass(frozen=True)
class CollectOptions:
    renderer: str = "auto"
    cameras: tuple[str, ...] | None = None  # None: all six
    image_size: tuple[int, int] | None = None  # None: 1600x900
    jpeg_quality: int = 85
    max_frames: int | None = None  # None: the whole clip
    camera_labels: tuple[str, ...] = ()  # dense labels per camera: depth, semantic, instance
    label_scale: int = DEFAULT_LABEL_SCALE  # labels at 1/scale of the camera resolution
    lidar: str = "raycast"  # "raycast" (the reference) or "depth" (read from depth images)
    visibility: str = "depth"  # boxes' visible share from "depth" images or the body "mask"
    post_process: str = "cpu"  # camera weather, resize and JPEG on the "cpu" or with "cuda"
    # sensors rendered and logged at this rate (10: every frame; 2: nuScenes' keyframes); the
    # ego's pose, IMU, GNSS and the lights are logged at every 10 Hz frame whatever the rate
    sensor_hz: int = 10

    @property
    def sensor_every(self) -> int:
        """Sensors at every n-th frame."""
        return topics.sensor_every(self.sensor_hz)

    def suite(self) -> SuiteOptions:
        return SuiteOptions(
            self.cameras,
            self.image_size,
            self.jpeg_quality,
            camera_labels=self.camera_labels,
            label_scale=self.label_scale,
            lidar=self.lidar,
            visibility=self.visibility,
            post_process=self.post_process,
        )


@dataclass
class JobResult:
    scenario_id: str
    # "collected", "skipped" (a finished log was there), "no ego" (nothing to mount the rig on:
    # curate first, or the source has no motor vehicle) or "failed"
    status: str
    frames: int = 0
    log_bytes: int = 0
    seconds: float = 0.0
    stage_seconds: dict[str, float] = field(default_factory=dict)
    peak_rss_bytes: int = 0
    renderer: str = ""
    error: str | None = None
    # frames collected on each Ray node (node id -> frames); empty for the local pool
    node_frames: dict[str, int] = field(default_factory=dict)
    # (began, ended, process id, seconds of set-up, first frame, frames captured) of each job
    # that went into this result, epoch seconds: where a run's wall time went, and which frames
    # each piece of a split clip got (`scripts/dev/bench_collect.py` draws its timeline)
    spans: list[tuple[float, float, int, float, int, int]] = field(default_factory=list)


def log_path(root: Path, scenario_id: str) -> Path:
    return Path(root) / LOGS_FOLDER / f"{scenario_id}.mcap"


_world: World | None = None  # this process's world, kept for the next clip on its map


@atexit.register
def _close_world() -> None:
    if _world is not None:
        _world.close()


def release_world() -> None:
    """Close this process's world and give its GL context back to the driver
    (`gl_context.release_context`), where a pool worker has nothing left to do before the run
    ends; a later clip sets a world up and makes a context again."""
    global _world
    _close_world()
    _world = None
    gl_context.release_context()


def remove_world_files() -> None:
    """Delete this process's world's temporary files (its twin's meshes) and nothing else:
    safe at any point, for a worker told to stop (`runner`'s SIGTERM handler), where `atexit`
    would not run."""
    if _world is not None:
        _world.twin.remove_files()


def _world_for(
    root: Path,
    scenario_id: str,
    renderer: str,
    post_process: str = "cpu",
    frames: range | None = None,
) -> World:
    global _world
    if post_process == "cuda" and not camera_gpu.cuda_started():
        if _world is not None:  # CUDA must start before any EGL context (camera_gpu.prepare)
            _world.close()
            _world = None
        camera_gpu.prepare(post_process)
    scenario = store.read_scenario(root, scenario_id)
    _world = world_for(
        _world, scenario, lambda map_id: store.read_map(root, map_id), renderer, frames,
        functools.partial(reuse.twin_plan, root),
    )  # fmt: skip
    return _world


def label_metadata(suite: SensorSuite, options: CollectOptions) -> dict[str, str]:
    """The log's `drivee2e.camera_labels` record: kinds, scale, size, units, the class table
    and the instance values' track ids."""
    camera = suite.rig.cameras[0]
    offset, scale = options.label_scale // 2, options.label_scale
    return {
        "kinds": ",".join(options.camera_labels),
        "scale": str(scale),
        "width": str(len(range(offset, camera.width, scale))),
        "height": str(len(range(offset, camera.height, scale))),
        "depth_unit": "mm (0: no hit or beyond 65.535 m)",
        "semantic_classes": json.dumps(list(SEMANTIC_CLASSES)),
        "instance_track_ids": json.dumps([t.track_id for t in suite.world.scenario.tracks]),
    }


@dataclass
class ClipSetup:
    """A clip's world and rig, ready to capture, and what its log's records say of them."""

    world: World
    suite: SensorSuite
    collection: dict[str, str]  # the log's drivee2e.collection record
    labels: dict[str, str] | None  # the log's drivee2e.camera_labels record


def open_clip(
    root: Path,
    scenario_id: str,
    options: CollectOptions,
    frames: range | None = None,
    stage_seconds: dict[str, float] | None = None,
) -> ClipSetup:
    """This process's world for the clip (its twin kept when the map is the same), set up for
    `frames` of it (all for None: `World.replay`), and the rig; the time it took is added to
    `stage_seconds["setup"]` where given."""
    tick = time.perf_counter()
    world = _world_for(Path(root), scenario_id, options.renderer, options.post_process, frames)
    suite = SensorSuite(world, options.suite())
    collection = {
        "renderer": world.renderer,
        "look": str(world.look_version),
        "jpeg_quality": str(options.jpeg_quality),
        "cameras": ",".join(c.name for c in suite.rig.cameras),
        "lidar": options.lidar,
        "post_process": options.post_process,
        "sensor_hz": str(options.sensor_hz),
    }
    if world.renderer == "gl":  # which driver drew the images (Mesa versions differ in pixels)
        collection["gl_driver"] = gl_context.gl_driver()
    labels = label_metadata(suite, options) if options.camera_labels else None
    if stage_seconds is not None:
        stage_seconds["setup"] = stage_seconds.get("setup", 0.0) + time.perf_counter() - tick
    return ClipSetup(world, suite, collection, labels)


def planned_frames(num_frames: int, max_frames: int | None) -> int:
    """How many of a clip's frames are collected: all, or the first `max_frames`."""
    return num_frames if max_frames is None else min(num_frames, max_frames)


def capture_frames(
    setup: ClipSetup,
    frames: Iterable[int],
    stage_seconds: dict[str, float],
    encode: Callable[[SensorFrame | StateFrame], None],
    on_frame: Callable[[int], None] | None = None,
    sensor_every: int = 1,
) -> int:
    """Capture `frames` in order, handing each to `encode` (timed as the write stage); returns
    how many were captured. Frames that are no multiple of `sensor_every` get only the ego's
    state (`SensorSuite.capture_state`)."""
    count = 0
    for frame in frames:
        if frame % sensor_every:
            captured: SensorFrame | StateFrame = setup.suite.capture_state(frame)
        else:
            captured = setup.suite.capture(frame)
        for stage, seconds in captured.seconds.items():
            stage_seconds[stage] += seconds
        tick = time.perf_counter()
        encode(captured)
        stage_seconds["write"] += time.perf_counter() - tick
        count += 1
        if on_frame is not None:
            on_frame(1)
    return count


def collect_clip(
    root: Path,
    scenario_id: str,
    options: CollectOptions,
    on_frame: Callable[[int], None] | None = None,
) -> JobResult:
    """Collect one clip into `root/logs/<scenario_id>.mcap` unless that log exists."""
    path = log_path(root, scenario_id)
    if path.exists():
        return JobResult(scenario_id, "skipped", log_bytes=path.stat().st_size)

    def work(result: JobResult) -> None:
        first = None if options.max_frames is None else range(options.max_frames)
        setup = open_clip(root, scenario_id, options, first, result.stage_seconds)
        result.renderer = setup.world.renderer
        scenario = setup.world.scenario
        frames = range(planned_frames(scenario.num_frames, options.max_frames))
        with log_writer(path, setup, options) as writer:
            result.frames = capture_frames(
                setup, frames, result.stage_seconds, writer.write, on_frame, options.sensor_every
            )
        result.status = "collected"
        result.log_bytes = path.stat().st_size

    return run_job(scenario_id, work)


def log_writer(path: Path, setup: ClipSetup, options: CollectOptions) -> LogWriter:
    """The writer of a clip's log at `path`, for the clip `setup` made, as every run writes it
    (one worker's, or a pool's head: `segments._write_head`)."""
    return LogWriter(
        path,
        setup.world.scenario,
        setup.world.intersection_map,
        setup.suite.rig,
        setup.suite.motion,
        setup.collection,
        setup.labels,
        sensor_every=options.sensor_every,
    )


def run_job(scenario_id: str, work: Callable[[JobResult], None], first_frame: int = 0) -> JobResult:
    """Run `work` on a fresh result, timed; a bad clip or a bug becomes the result's error (with
    where a bug happened) instead of an exception, so one clip cannot stop the others."""
    start, began = time.perf_counter(), time.time()
    result = JobResult(scenario_id, "failed", stage_seconds=dict.fromkeys(JOB_STAGES, 0.0))
    try:
        work(result)
    except (DriveE2EError, ValueError, KeyError, OSError) as error:
        result.status, result.error = "failed", f"{type(error).__name__}: {error}"
    except Exception as error:  # a bug must not stop the other clips; keep where it happened
        where = traceback.extract_tb(error.__traceback__)[-1]
        result.status = "failed"
        result.error = (
            f"{type(error).__name__}: {error} ({Path(where.filename).name}:{where.lineno})"
        )
    result.seconds = time.perf_counter() - start
    setup = result.stage_seconds["setup"]
    result.spans = [(began, began + result.seconds, os.getpid(), setup, first_frame, result.frames)]
    result.peak_rss_bytes = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    return result
