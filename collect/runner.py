"""Runs collection jobs over a data root: the local process pool (default) or Ray, a progress
bar in frames/s, resume (finished logs are skipped, stale partial logs removed), the frame
index `logs/index.parquet`, and a summary with every failure's reason.

One collector per data root at a time: `logs/.collect.lock` is held for the whole run.
"""

from __future__ import annotations

import fcntl
import io
import multiprocessing
import os
import queue
import signal
import time
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from drivee2e_data import store
from drivee2e_data.collect.job import LOGS_FOLDER, CollectOptions, JobResult, collect_clip, log_path
from drivee2e_data.errors import DriveE2EError, LogFormatError
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.logs.writer import PARTIAL_SUFFIX
from drivee2e_data.processes import stop_pool
from drivee2e_data.sensors.ego_state import ego_motion

BACKENDS = ("local", "ray")
INDEX_NAME = "index.parquet"


@dataclass
class CollectSummary:
    results: list[JobResult] = field(default_factory=list)
    wall_seconds: float = 0.0
    index_rows: int = 0

    def of(self, status: str) -> list[JobResult]:
        return [r for r in self.results if r.status == status]

    @property
    def frames(self) -> int:
        return sum(r.frames for r in self.of("collected"))

    @property
    def frames_per_second(self) -> float:
        return self.frames / self.wall_seconds if self.wall_seconds > 0 else 0.0

    @property
    def log_bytes(self) -> int:
        return sum(r.log_bytes for r in self.results if r.status != "failed")


@contextmanager
def _run_lock(logs: Path) -> Iterator[None]:
    logs.mkdir(parents=True, exist_ok=True)
    with open(logs / ".collect.lock", "w") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise DriveE2EError(f"{logs}: another drivee2e collect is running here") from None
        yield


def _without_ego(root: Path, scenario_id: str) -> bool:
    """Whether the clip's meta names no ego (a bundle that cannot be read is left to its job,
    which reports why)."""
    try:
        return store.read_meta(root, scenario_id).get("ego_id") is None
    except DriveE2EError:
        return False


def _planned_frames(root: Path, scenario_id: str, options: CollectOptions) -> int:
    try:
        _, frames = store.read_timeline(root, scenario_id)  # meta.json only: the job reads the rest
    except DriveE2EError:
        return 0  # its job fails with the reason; the other clips go ahead
    return frames if options.max_frames is None else min(frames, options.max_frames)


def collect(
    root: Path,
    options: CollectOptions,
    workers: int = 1,
    backend: str = "local",
    only: list[str] | None = None,
    progress: Callable[[int, int], Callable[[int], None]] | None = None,
) -> CollectSummary:
    """Collect every clip under `root` (or those in `only`) that has no log yet.

    `progress(total_frames, clips)` may return a callable that is told of finished frames.
    """
    root = Path(root)
    if backend not in BACKENDS:
        raise DriveE2EError(f"backend {backend!r}: expected one of {', '.join(BACKENDS)}")
    available = store.scenario_ids(root)
    if not available:
        raise DriveE2EError(f"{root}: no scenarios (expected {root}/scenarios/<id>/)")
    scenario_ids = available
    if only:
        unknown = [s for s in only if s not in available]
        if unknown:
            raise DriveE2EError(f"{root}: no scenario {unknown[0]!r} (see drivee2e scenarios)")
        scenario_ids = [s for s in available if s in only]
    logs = root / LOGS_FOLDER
    summary = CollectSummary()
    start = time.perf_counter()
    with _run_lock(logs):
        for stale in logs.glob(f".*{PARTIAL_SUFFIX}"):
            stale.unlink()  # a crashed run's unfinished log; its clip is redone
        pending = []
        for scenario_id in scenario_ids:
            path = log_path(root, scenario_id)
            if path.exists():
                summary.results.append(_existing(scenario_id, path))
            elif _without_ego(root, scenario_id):
                summary.results.append(JobResult(scenario_id, "no ego"))
            else:
                pending.append(scenario_id)
        total = sum(_planned_frames(root, s, options) for s in pending)
        tick = progress(total, len(pending)) if progress else None
        try:
            if backend == "ray":
                summary.results.extend(_run_ray(root, pending, options, tick))
            elif workers <= 1:
                summary.results.extend(collect_clip(root, s, options, tick) for s in pending)
            else:
                summary.results.extend(_run_pool(root, pending, options, workers, tick))
        except KeyboardInterrupt:
            for partial in logs.glob(f".*{PARTIAL_SUFFIX}"):
                partial.unlink()  # stopped workers' unfinished logs; finished ones stay
            raise
        summary.wall_seconds = time.perf_counter() - start
        summary.index_rows = write_index(root)
    order = {s: i for i, s in enumerate(scenario_ids)}
    summary.results.sort(key=lambda r: order[r.scenario_id])
    return summary


def _existing(scenario_id: str, path: Path) -> JobResult:
    """A log already under its final name is never rewritten: skipped when it reads as a
    finished log, reported (and left for the user to delete) when it does not."""
    try:
        LogReader(path).close()
    except LogFormatError as error:
        return JobResult(
            scenario_id, "failed", error=f"{error}; delete it to collect the clip again"
        )
    return JobResult(scenario_id, "skipped", log_bytes=path.stat().st_size)


_frames_done: multiprocessing.Queue | None = None


# Mesa's llvmpipe renders with a thread per core; with a worker per core the threads only fight
# (measured: 1.43 -> 1.56 frames/s with 2 workers on 2 cores), so each worker renders on one.
# OpenCV's and torch's thread pools likewise: a pool per worker, each as large as the host.
WORKER_ENVIRONMENT = {"LP_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


def _init_worker(frames_done: multiprocessing.Queue) -> None:
    global _frames_done
    _frames_done = frames_done
    for name, value in WORKER_ENVIRONMENT.items():
        os.environ.setdefault(name, value)
    import cv2  # torch, where the GPU post-processing imports it, reads OMP_NUM_THREADS

    cv2.setNumThreads(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle


def _pooled_clip(root: Path, scenario_id: str, options: CollectOptions) -> JobResult:
    frames_done = _frames_done
    return collect_clip(root, scenario_id, options, frames_done.put if frames_done else None)


def _run_pool(
    root: Path,
    scenario_ids: list[str],
    options: CollectOptions,
    workers: int,
    tick: Callable[[int], None] | None,
) -> list[JobResult]:
    # spawn: a fresh interpreter per worker, no pybullet or EGL state inherited from the parent
    context = multiprocessing.get_context("spawn")
    frames_done = context.Queue()
    results: list[JobResult] = []
    pool = ProcessPoolExecutor(
        max_workers=workers, mp_context=context, initializer=_init_worker, initargs=(frames_done,)
    )
    try:
        futures: dict[Future, str] = {
            pool.submit(_pooled_clip, root, s, options): s for s in scenario_ids
        }
        remaining = set(futures)
        while remaining:
            done, remaining = wait(remaining, timeout=0.25, return_when=FIRST_COMPLETED)
            _drain(frames_done, tick)
            for future in done:
                try:
                    results.append(future.result())
                except BrokenProcessPool:
                    results.append(
                        JobResult(futures[future], "failed", error="the worker process died")
                    )
        _drain(frames_done, tick)
    except BaseException:
        stop_pool(pool)
        raise
    pool.shutdown()
    return results


def _drain(frames_done: multiprocessing.Queue, tick: Callable[[int], None] | None) -> None:
    count = 0
    while True:
        try:
            count += frames_done.get_nowait()
        except queue.Empty:
            break
    if tick is not None and count:
        tick(count)


def _run_ray(
    root: Path,
    scenario_ids: list[str],
    options: CollectOptions,
    tick: Callable[[int], None] | None,
) -> list[JobResult]:
    try:
        import ray
    except ImportError:
        raise DriveE2EError("--backend ray needs Ray: pip install 'drivee2e-data[ray]'") from None
    # joins the cluster named by RAY_ADDRESS, or starts a local one
    ray.init(ignore_reinit_error=True, log_to_driver=False)
    remote_clip = ray.remote(num_cpus=1)(collect_clip).options(
        runtime_env={"env_vars": WORKER_ENVIRONMENT}
    )
    pending = {remote_clip.remote(root, s, options): s for s in scenario_ids}
    results: list[JobResult] = []
    try:
        _gather_ray(ray, pending, results, tick)
    except KeyboardInterrupt:
        for reference in pending:
            ray.cancel(reference, force=True)
        raise
    return results


def _gather_ray(
    ray: Any,
    pending: dict[Any, str],
    results: list[JobResult],
    tick: Callable[[int], None] | None,
) -> None:
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        for reference in done:
            scenario_id = pending.pop(reference)
            try:
                result = ray.get(reference)
            except Exception as error:  # a task lost with its node
                result = JobResult(scenario_id, "failed", error=f"Ray task failed: {error}")
            results.append(result)
            if tick is not None:
                tick(result.frames)


def write_index(root: Path) -> int:
    """`logs/index.parquet`: one row per collected frame of every finished log (scenario, frame,
    t_ns, ego pose at the rear axle, speed, command, behaviour and conditions); returns rows."""
    root = Path(root)
    columns: dict[str, list] = {name: [] for name in INDEX_SCHEMA.names}
    for path in sorted((root / LOGS_FOLDER).glob("*.mcap")):
        try:
            with LogReader(path) as log:
                frames = list(log.frames)
        except LogFormatError:
            continue  # not ours to index; `drivee2e logs --validate` names what is wrong
        try:
            scenario = store.read_scenario(root, path.stem, require_map=False)
            motion = ego_motion(scenario)
        except (DriveE2EError, ValueError):
            continue  # the log outlived or no longer matches its scenario: nothing to index
        behavior = scenario.behavior
        for frame in frames:
            columns["scenario_id"].append(scenario.scenario_id)
            columns["map_id"].append(scenario.map_id)
            columns["frame"].append(frame)
            columns["t_ns"].append(int(scenario.t_ns[frame]))
            columns["x_m"].append(float(motion.x_m[frame]))
            columns["y_m"].append(float(motion.y_m[frame]))
            columns["yaw_rad"].append(float(motion.yaw_rad[frame]))
            columns["speed_mps"].append(float(motion.speed_mps[frame]))
            columns["command"].append(int(motion.command[frame]))
            columns["sub_scenario"].append(behavior.sub_scenario.value if behavior else None)
            columns["category"].append(behavior.category.value if behavior else None)
            columns["weather"].append(scenario.conditions.weather.value)
            columns["time_of_day"].append(scenario.conditions.time_of_day.value)
            columns["source"].append(scenario.source)
    table = pa.table(columns, schema=INDEX_SCHEMA)
    buffer = io.BytesIO()
    pq.write_table(table, buffer)
    store.write_bytes_atomic(root / LOGS_FOLDER / INDEX_NAME, buffer.getvalue())
    return table.num_rows


INDEX_SCHEMA = pa.schema(
    [
        ("scenario_id", pa.string()),
        ("map_id", pa.string()),
        ("frame", pa.int32()),
        ("t_ns", pa.int64()),
        ("x_m", pa.float64()),
        ("y_m", pa.float64()),
        ("yaw_rad", pa.float64()),
        ("speed_mps", pa.float64()),
        ("command", pa.int8()),
        ("sub_scenario", pa.string()),
        ("category", pa.string()),
        ("weather", pa.string()),
        ("time_of_day", pa.string()),
        ("source", pa.string()),
    ]
)
