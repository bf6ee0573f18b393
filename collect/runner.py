"""Runs collection jobs over a data root: the local process pool (default) or Ray, a progress
bar in frames/s, resume (finished logs are skipped, stale partial logs removed), the frame
index `logs/index.parquet`, and a summary with every failure's reason.

One collector per data root at a time: `logs/.collect.lock` is held for the whole run.
"""

from __future__ import annotations

import atexit
import collections
import contextlib
import fcntl
import functools
import io
import multiprocessing
import multiprocessing.util
import os
import queue
import shutil
import signal
import time
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from drivee2e_data import store
from drivee2e_data.collect import segments
from drivee2e_data.collect.balance import (
    MIN_SPLIT_SENSOR_FRAMES,
    SETUP_FRAMES,
    Candidate,
    SetupCosts,
    sensor_frames,
    split_order,
)
from drivee2e_data.collect.job import (
    LOGS_FOLDER,
    CollectOptions,
    JobResult,
    collect_clip,
    log_path,
    planned_frames,
    release_world,
    remove_world_files,
)
from drivee2e_data.collect.preload import start_worker_server, worker_context
from drivee2e_data.collect.segments import Job, WorkUnit
from drivee2e_data.errors import DriveE2EError, LogFormatError
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.logs.writer import PARTIAL_SUFFIX
from drivee2e_data.processes import (
    SPAWN,
    WORKER_THREADS,
    clean_up_when_stopped,
    worker_pool,
)
from drivee2e_data.scenario import Scenario
from drivee2e_data.sensors.ego_state import EgoMotion, ego_motion
from drivee2e_data.sim import egl_devices, gl_context, reuse
from drivee2e_data.sim.egl_devices import contexts_at_once
from drivee2e_data.sim.twin import mesh_folder

BACKENDS = ("local", "ray")
# threads writing clips' logs from their segments beside the pool: a log is a copy of its
# segments' chunks (0.1-1 s a clip). Two for up to 16 workers (four did not shorten the run's
# end on an H100 host with 16, docs/benchmarks.md, "ninth session"); one more per 8 workers
# past that, up to 8: a large pool's last segments end together (16 clips' with 32 workers,
# 64 with 128). On a 2-H100 host four gave 1.008x two, alternating (within the spread;
# docs/benchmarks.md, "eighteenth session")
MERGE_THREADS = 2
MERGE_WORKERS_PER_THREAD = 8
MAX_MERGE_THREADS = 8


def merge_threads(workers: int) -> int:
    """Threads writing logs from segments for a pool of `workers`."""
    return min(MAX_MERGE_THREADS, max(MERGE_THREADS, workers // MERGE_WORKERS_PER_THREAD))


# units a pool may split off running ones, per worker: the last frames of a run are handed out
# in halves, so a few a worker balance it
SPLITS_PER_WORKER = 4
INDEX_NAME = "index.parquet"


@dataclass
class CollectSummary:
    results: list[JobResult] = field(default_factory=list)
    wall_seconds: float = 0.0
    index_rows: int = 0
    workers: int = 1  # processes (local) or task slots (Ray) the units were planned for
    started: float = 0.0  # epoch seconds, as JobResult.spans
    index_seconds: float = 0.0  # writing logs/index.parquet, the run's last step

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

    @property
    def node_frames(self) -> dict[str, int]:
        """Frames collected on each Ray node (empty for the local pool)."""
        total: dict[str, int] = {}
        for result in self.results:
            for node, frames in result.node_frames.items():
                total[node] = total.get(node, 0) + frames
        return total


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


def frames_to_collect(root: Path, scenario_id: str, max_frames: int | None) -> int | None:
    """How many frames of the clip a run collects, from its meta.json alone (the job reads the
    rest); None where that cannot be read (its job fails with the reason)."""
    try:
        _, frames = store.read_timeline(root, scenario_id)
    except DriveE2EError:
        return None
    return planned_frames(frames, max_frames)


def _plan(
    root: Path,
    scenario_ids: list[str],
    options: CollectOptions,
    workers: int,
    whole_clips: bool = True,
) -> tuple[list[Job], dict[str, int], dict[str, str]]:
    """The jobs for these clips (see `segments.plan_jobs`), each clip's frames and its map.
    Segment files a crashed run finished are kept and only the frames they lack are planned;
    a clip whose bundle cannot be read gets one whole unit, whose job reports why."""
    segments.remove_temporary(root)
    clip_frames, covered, maps, unreadable = {}, {}, {}, []
    for scenario_id in scenario_ids:
        frames = frames_to_collect(root, scenario_id, options.max_frames)
        if frames is None:
            unreadable.append(WorkUnit(scenario_id, 0, 0, whole=True))
            continue
        clip_frames[scenario_id] = frames
        maps[scenario_id] = store.read_meta(root, scenario_id).get("map_id", scenario_id)
        kept = []
        for path, header in segments.finished_segments(root, scenario_id, options):
            start, stop = header["start"], header["stop"]
            if stop > frames or any(start < b and a < stop for a, b in kept):
                segments.discard(path)  # made for a longer --max-frames, or overlapping: redone
            elif "head" not in header and not segments.intact(path, header):
                segments.discard(path)  # left with holes by a machine that stopped: redone
            else:
                kept.append((start, stop))
        covered[scenario_id] = kept
    jobs = segments.plan_jobs(
        clip_frames, covered, workers, maps, options.sensor_every, whole_clips
    )
    return [*jobs, *((unit,) for unit in unreadable)], clip_frames, maps


def run_unit(
    root: Path,
    unit: WorkUnit,
    options: CollectOptions,
    on_frame: Callable[[int], None] | None = None,
    claim: Callable[[int], bool] | None = None,
    on_setup: Callable[[float], None] | None = None,
) -> JobResult:
    """A whole clip into its log, or a segment into its segment file (`claim` and `on_setup`:
    see `segments.collect_segment`)."""
    if unit.whole:
        return collect_clip(root, unit.scenario_id, options, on_frame)
    return segments.collect_segment(root, unit, options, on_frame, claim, on_setup)


class _ClipTracker:
    """Gathers units' results into one result per clip and writes a clip's log from its
    segments (`segments.SegmentedLog`): appended to as they finish, where a pool runs, and
    made final once they are all there."""

    def __init__(
        self,
        root: Path,
        options: CollectOptions,
        units: list[WorkUnit],
        clip_frames: dict[str, int],
    ) -> None:
        self.root, self.options, self.clip_frames = root, options, clip_frames
        self.waiting: dict[str, int] = {}
        for unit in units:
            self.waiting[unit.scenario_id] = self.waiting.get(unit.scenario_id, 0) + 1
        self.clips: dict[str, JobResult] = {}
        self.index_rows: dict[str, dict[str, list]] = {}  # of logs written here (`write_log`)
        # clips whose segments an earlier run finished, all of them, but whose log it did not
        # write (it stopped in between): their logs are written first
        self.ready = [s for s, frames in clip_frames.items() if frames and s not in self.waiting]
        for scenario_id in self.ready:
            self.clips[scenario_id] = JobResult(scenario_id, "collected")
        self.logs = {
            scenario_id: segments.SegmentedLog(root, scenario_id, options, frames)
            for scenario_id, frames in clip_frames.items()
        }

    def add(self, unit: WorkUnit) -> None:
        """A unit split off a running one (`_run_pool`): the clip waits for it too."""
        self.waiting[unit.scenario_id] += 1

    def finished(self, unit: WorkUnit, result: JobResult) -> str | None:
        """Count in a unit's result; returns the clip's id when its segments are all done and
        its log is to be written (`merge`)."""
        clip = self.clips.get(unit.scenario_id)
        if clip is None:
            clip = self.clips[unit.scenario_id] = JobResult(
                unit.scenario_id,
                result.status,
                stage_seconds=dict.fromkeys(result.stage_seconds, 0.0),
            )
        _add(clip, result)
        if result.status == "failed" and clip.error is None:
            where = "" if unit.whole else f"frames {unit.start}-{unit.stop - 1}: "
            clip.status, clip.error = "failed", f"{where}{result.error}"
        self.waiting[unit.scenario_id] -= 1
        if self.waiting[unit.scenario_id] or unit.whole or clip.status == "failed":
            return None
        return unit.scenario_id

    def appends(self, unit: WorkUnit, result: JobResult) -> bool:
        """Whether the unit's finished segment may continue its clip's log before the clip's
        other units are done (`append`)."""
        return not unit.whole and result.status == "collected" and result.frames > 0

    def append(self, scenario_id: str) -> None:
        """Copy the clip's finished segments that continue its log (`SegmentedLog.append`); a
        pool runs it in a thread of this process while its workers collect the rest."""
        self.logs[scenario_id].append()

    def write_log(self, scenario_id: str) -> JobResult:
        """The clip's log made final from its segments (`SegmentedLog.finish`), then its index
        rows (kept for `write_index`); a pool runs it in a thread of this process."""
        log = self.logs[scenario_id]
        result = log.finish()
        if result.status == "collected":
            rows = index_rows(self.root, log_path(self.root, scenario_id), log.scenario())
            if rows is not None:
                self.index_rows[scenario_id] = rows
        return result

    def merge(self, scenario_id: str) -> None:
        """Write the clip's log from its segments (in this process)."""
        self.merged(scenario_id, self.write_log(scenario_id))

    def merged(self, scenario_id: str, result: JobResult) -> None:
        """Count in the result of writing the clip's log (`segments.merge_clip`): its time in the
        write stage, but not in the clip's seconds or spans, which are the workers' (the log is
        written by this process, beside them)."""
        clip = self.clips[scenario_id]
        clip.stage_seconds["write"] = clip.stage_seconds.get("write", 0.0) + result.seconds
        clip.log_bytes = result.log_bytes
        if result.status == "failed":
            clip.status, clip.error = "failed", result.error

    def results(self) -> list[JobResult]:
        return list(self.clips.values())

    def close(self) -> None:
        """Stop writing the logs of clips that did not finish (failed, or the run stopped):
        their partial files go, their heads and segments stay (`SegmentedLog.close`)."""
        for log in self.logs.values():
            log.close()


def _add(total: JobResult, part: JobResult) -> None:
    total.frames += part.frames
    total.seconds += part.seconds
    total.log_bytes = max(total.log_bytes, part.log_bytes)
    total.peak_rss_bytes = max(total.peak_rss_bytes, part.peak_rss_bytes)
    total.renderer = total.renderer or part.renderer
    for node, frames in part.node_frames.items():
        total.node_frames[node] = total.node_frames.get(node, 0) + frames
    total.spans.extend(part.spans)
    for stage, seconds in part.stage_seconds.items():
        total.stage_seconds[stage] = total.stage_seconds.get(stage, 0.0) + seconds


def collect(
    root: Path,
    options: CollectOptions,
    workers: int = 1,
    backend: str = "local",
    only: list[str] | None = None,
    progress: Callable[[int, int], Callable[[int], None]] | None = None,
    gpus: tuple[int, ...] = (),
) -> CollectSummary:
    """Collect every clip under `root` (or those in `only`) that has no log yet.

    `progress(total_frames, clips)` may return a callable that is told of finished frames.
    `gpus`: EGL devices the workers' GL contexts are made on, round robin (() for the default
    device; `sim.egl_devices`).
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
    summary = CollectSummary(started=time.time())
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
        if backend == "local" and workers > 1 and pending:  # its imports overlap the planning
            start_worker_server()
        if backend == "ray" and pending:  # units for every CPU of the cluster
            workers = max(workers, _start_ray())
        # the local pool splits running segments for idle workers: no piece is a whole clip
        pooled = backend == "local" and workers > 1
        jobs, clip_frames, maps = _plan(root, pending, options, workers, whole_clips=not pooled)
        units = [unit for job in jobs for unit in job]
        total = sum(u.frames for u in units)
        tick = progress(total, len(pending)) if progress else None
        tracker = _ClipTracker(root, options, units, clip_frames)

        def index() -> None:
            indexing = time.perf_counter()
            summary.index_rows = write_index(root, tracker.index_rows)
            summary.index_seconds = time.perf_counter() - indexing

        try:
            if backend == "ray":
                _run_ray(root, jobs, options, tracker, tick, gpus)
            elif workers <= 1 or not jobs:
                for scenario_id in tracker.ready:
                    tracker.merge(scenario_id)
                for unit in units:
                    merge = tracker.finished(unit, run_unit(root, unit, options, tick))
                    if merge is not None:
                        tracker.merge(merge)
            else:
                workers = min(workers, len(jobs))  # no idle workers
                _run_pool(root, jobs, options, workers, tracker, tick, gpus, maps, then=index)
            summary.results.extend(tracker.results())
        except KeyboardInterrupt:
            for partial in logs.glob(f".*{PARTIAL_SUFFIX}"):
                partial.unlink()  # stopped workers' unfinished logs; finished ones stay
            segments.remove_temporary(root)  # finished segments stay: a rerun resumes them
            raise
        finally:
            tracker.close()
        try:
            (logs / segments.SEGMENTS_FOLDER).rmdir()  # every clip's segments merged
        except OSError:
            pass  # none was made, or a failed clip's segments stay for the rerun
        summary.workers = workers
        if summary.index_seconds == 0.0:  # not yet written beside the pool's exit
            index()
        summary.wall_seconds = time.perf_counter() - start
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


# below the queues' own exit steps (`multiprocessing.queues`: -5 joins a queue's feeding thread)
WORKER_FILES_EXIT_PRIORITY = -10
_frames_done: multiprocessing.Queue | None = None
_units_done: multiprocessing.Queue | None = None  # (slot, JobResult) as each unit ends
_setups_done: multiprocessing.Queue | None = None  # (slot, pid, seconds) as each world is set up
_claims: Any = None  # the pool's `_Claims.shared`
_given_back: Any = None  # (count, all given back): `_give_back`'s
# how long a worker that gave its context back waits for the others at most: they take the
# run's last frames (a few seconds); past this the pool lost a worker and is stopped anyway
GIVE_BACK_WAIT_S = 600.0


def context_at_start(options: CollectOptions) -> bool:
    """Whether a pool worker makes its GL context as it starts: where its worlds will draw with
    one (the GL renderer, asked for or chosen by "auto" where it can be made), unless the
    cameras are finished with CUDA, which must start before any EGL context
    (`camera_gpu.prepare`). Made at once, the contexts are made as the pool's server forks the
    workers, one after another, rather than all in the workers' first set-ups together: 1.03x
    frames a second with 32 workers on an H100 host (docs/benchmarks.md)."""
    return options.renderer in ("auto", "gl") and options.post_process == "cpu"


def _init_worker(
    frames_done: multiprocessing.Queue,
    units_done: multiprocessing.Queue,
    setups_done: multiprocessing.Queue,
    started: Any,
    gpus: tuple[int, ...],
    claims: Any,
    plans: str,
    make_context: bool = False,
    context_slots: Any = None,
    given_back: Any = None,
) -> None:
    global _frames_done, _units_done, _setups_done, _claims, _given_back
    _frames_done, _units_done, _setups_done, _claims = frames_done, units_done, setups_done, claims
    _given_back = given_back
    reuse.share_in(Path(plans))  # what any worker planned or wrote is there for all
    with started.get_lock():  # this worker's number, for its GPU
        worker, started.value = started.value, started.value + 1
    egl_devices.use_device(egl_devices.device_for_worker(worker, gpus))
    if make_context:  # `context_at_start`, a few workers at a time (`contexts_at_once`)
        with context_slots if context_slots is not None else contextlib.nullcontext():
            gl_context.gl_available()
    # one thread each for OpenCV too (llvmpipe's, OpenBLAS's, torch's: `one_thread_per_worker`;
    # llvmpipe with a thread per core and a worker per core: 1.43 -> 1.56 frames/s on 2 cores)
    import cv2

    cv2.setNumThreads(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    clean_up_when_stopped(remove_world_files)
    atexit.register(_exit_at_once)  # run first: handlers run last registered first
    # a worker forked from the pool's server leaves by `os._exit` without running `atexit`:
    # its world's files go with multiprocessing's own exit steps, after its queues flushed
    multiprocessing.util.Finalize(None, remove_world_files, exitpriority=WORKER_FILES_EXIT_PRIORITY)


def _exit_at_once() -> None:
    """A pool worker's exit once the pool is shut down: its twin's files deleted, then out,
    without closing the world (pybullet, the GL context) or finalising the interpreter. Its
    results and progress were sent before (`multiprocessing` flushes its queues ahead of
    `atexit`), and the system frees the rest; the orderly way kept the run waiting a second or
    more after its last frame on an H100 host (docs/benchmarks.md, "eighth session")."""
    remove_world_files()
    os._exit(0)


def _pooled_job(
    root: Path, job: Job, options: CollectOptions, slots: tuple[int, ...]
) -> list[JobResult]:
    """A job's units in order, in a pool worker, each claiming its frames in its slot of
    `_claims`; a failed unit does not stop the next. Each unit's result is also sent as it
    ends (`_units_done`), so that the parent writes a clip's log once its last unit is done
    rather than when the job holding it ends, and its world's set-up time as the set-up ends
    (`_setups_done`), so that the parent knows what a world costs before the units end (at 2
    Hz most end with the run)."""
    frames_done, results = _frames_done, []
    for unit, slot in zip(job, slots, strict=True):
        claim = functools.partial(_Claims.claim, _claims, slot)
        on_setup = None
        if _setups_done is not None:
            on_setup = functools.partial(_report_setup, _setups_done, slot)
        on_frame = frames_done.put if frames_done else None
        result = run_unit(root, unit, options, on_frame, claim, on_setup)
        if _units_done is not None:
            _units_done.put((slot, result))
        results.append(result)
    return results


def _give_back(workers: int) -> list[JobResult]:
    """A pool worker's last job, handed out once nothing is left to hand out or split (the
    run's tail): its world closed and its GL context given back to the driver
    (`job.release_world`), then held here until all `workers` have done the same, so that each
    worker takes one of these jobs and none takes two. NVIDIA's driver frees contexts one
    process at a time (32 took 0.6 s as the workers exited after the last frame, on a 2-H100
    host): freed beside the last workers' frames instead (docs/benchmarks.md, twenty-fifth
    session). A worker given a job after this makes a new context."""
    release_world()
    given_back, everyone = _given_back
    with given_back.get_lock():
        given_back.value += 1
        if given_back.value >= workers:
            everyone.set()
    # bounded: a pool short of workers (one died) is broken and stopped anyway
    everyone.wait(timeout=GIVE_BACK_WAIT_S)
    return []


def _report_setup(setups_done: multiprocessing.Queue, slot: int, seconds: float) -> None:
    setups_done.put((slot, os.getpid(), seconds))


class _Claims:
    """The frames each unit of a pool may still capture, shared with the workers. Slot k holds
    the frame its unit captures next and the frame it stops before; a worker claims each frame
    before capturing it (`claim`), and the parent moves a running unit's stop back to hand the
    rest to an idle worker (`split`), under one lock, so no frame is captured twice or never."""

    def __init__(self, slots: int, context: multiprocessing.context.BaseContext = SPAWN) -> None:
        self.shared = context.Array("q", 2 * slots)
        self.used = 0

    @property
    def full(self) -> bool:
        return self.used * 2 == len(self.shared)

    def add(self, unit: WorkUnit) -> int:
        """A slot for `unit` (there must be one left: `full`)."""
        if self.full:
            raise RuntimeError("no slot left for another unit")
        slot, self.used = self.used, self.used + 1
        with self.shared.get_lock():
            self.shared[2 * slot], self.shared[2 * slot + 1] = unit.start, unit.stop
        return slot

    @staticmethod
    def claim(shared: Any, slot: int, frame: int) -> bool:
        """In a worker: whether `frame` is still this unit's to capture (then it is taken)."""
        with shared.get_lock():
            if frame >= shared[2 * slot + 1]:
                return False
            shared[2 * slot] = frame + 1
            return True

    def remaining(self, slot: int) -> int:
        return self.shared[2 * slot + 1] - self.shared[2 * slot]

    def begun(self, slot: int, unit: WorkUnit) -> bool:
        """Whether the unit's worker has claimed its first frame."""
        return self.shared[2 * slot] > unit.start

    def left(self, slot: int, sensor_every: int) -> int:
        """The sensor frames `slot` has left."""
        return sensor_frames(self.shared[2 * slot], self.remaining(slot), sensor_every)

    def split(
        self, slot: int, unit: WorkUnit, sensor_every: int, setup_frames: int = SETUP_FRAMES
    ) -> WorkUnit | None:
        """The frames of `slot` (running `unit`) an idle worker takes: all of a unit not begun,
        else the later half less the taker's set-up (`setup_frames` sensor frames), from a
        sensor frame on; None when fewer than `MIN_SPLIT_SENSOR_FRAMES` sensor frames would
        go."""
        with self.shared.get_lock():
            position, stop = self.shared[2 * slot], self.shared[2 * slot + 1]
            at = position
            if position > unit.start:
                at = position + (stop - position + setup_frames * sensor_every) // 2
                at = -(-at // sensor_every) * sensor_every  # the next sensor frame
            if stop - at < MIN_SPLIT_SENSOR_FRAMES * sensor_every:
                return None
            self.shared[2 * slot + 1] = at
        return WorkUnit(unit.scenario_id, at, stop)


def _run_pool(
    root: Path,
    jobs: list[Job],
    options: CollectOptions,
    workers: int,
    tracker: _ClipTracker,
    tick: Callable[[int], None] | None,
    gpus: tuple[int, ...] = (),
    maps: dict[str, str] | None = None,
    then: Callable[[], None] | None = None,
) -> None:
    """Jobs on a pool of worker processes, longest first, handed out as workers free up (one
    queued ahead for each). Once none is waiting, a worker that frees up takes frames of a
    running job (`balance.split_order`): the later half of a running unit, less its set-up
    (`_Claims.split`), or a unit its worker has not begun, whichever ends a job soonest,
    counting a world on the map its own shows (`maps`: each clip's) as a replay; the set-ups
    are measured as the pool runs (`balance.SetupCosts`). A clip's conditions make its frames
    up to 1.3x dearer than another's, so equal shares of frames finish apart, and the pool's
    wall time is then its even share plus about a world's set-up. A clip whose segments are
    all done has its log written at once by a thread of this process: writing a log from
    segments is a copy of their chunks, so it takes no worker and the logs get written while
    the collection goes on; the thread makes the log's index rows too. `then` runs after the
    last job, while the workers exit."""
    context = worker_context()
    frames_done, units_done, setups_done = context.Queue(), context.Queue(), context.Queue()
    started = context.Value("i", 0)
    units = sum(len(job) for job in jobs)
    claims = _Claims(units + SPLITS_PER_WORKER * workers, context)
    plans = mesh_folder()  # the run's twin plans and shape files (`reuse`), removed with the pool
    given_back = (context.Value("i", 0), context.Event())  # `_give_back`'s count, and all done
    initargs = (frames_done, units_done, setups_done, started, gpus, claims.shared, str(plans),
                context_at_start(options), context.Semaphore(contexts_at_once(gpus)),
                given_back)  # fmt: skip
    with (
        _removed_after(plans),
        worker_pool(workers, _init_worker, initargs, context) as pool,
        ThreadPoolExecutor(merge_threads(workers), thread_name_prefix="merge") as writers,
    ):
        waiting = collections.deque(jobs)
        running: dict[Future, Job | str] = {}  # a job, or the clip whose log is being written
        slots: dict[Future, tuple[int, ...]] = {}  # a job's units' slots in `claims`
        unit_in: dict[int, WorkUnit] = {}  # each slot's unit
        ended: set[int] = set()  # the slots whose units' results were taken in

        def submit(job: Job) -> None:
            taken = tuple(claims.add(unit) for unit in job)
            future = pool.submit(_pooled_job, root, job, options, taken)
            running[future], slots[future] = job, taken
            unit_in.update(zip(taken, job, strict=True))

        maps_of = maps or {}
        idle_maps: collections.deque[str | None] = collections.deque()  # freed workers' worlds

        costs = SetupCosts(options.sensor_every)
        worker_maps: dict[int, str] = {}  # process id -> the map its world shows

        def split_one() -> bool:
            """Give an idle worker the frames that end a running job soonest (`split_order`)."""
            if claims.full:
                return False
            every = options.sensor_every
            candidates, units_of = [], {}
            for future, job in running.items():
                if isinstance(job, str):
                    continue
                ahead, previous = 0, None
                for k, (unit, slot) in enumerate(zip(job, slots[future], strict=True)):
                    left, begun = claims.left(slot, every), claims.begun(slot, unit)
                    same = previous is None or maps_of.get(previous) == maps_of.get(
                        unit.scenario_id
                    )
                    # a job's first unit not begun was just handed out (a queued job would have
                    # been taken by the idle worker): splitting it would only take it from its
                    # worker
                    if k or begun:
                        candidates.append(
                            Candidate(slot, unit.scenario_id, left, begun, ahead, same)
                        )
                        units_of[slot] = unit
                    if k and not begun and left:
                        ahead += costs.frames(new_world=not same)
                    ahead += left
                    previous = unit.scenario_id
            taker_map = idle_maps[0] if idle_maps else None
            for candidate, setup in split_order(candidates, taker_map, maps_of, costs):
                unit = units_of[candidate.slot]
                piece = claims.split(candidate.slot, unit, every, setup)
                if piece is not None:
                    tracker.add(piece)
                    submit((piece,))
                    if idle_maps:
                        idle_maps.popleft()
                    return True
            return False

        def set_up(slot: int, pid: int, seconds: float) -> None:
            """A unit's world set up (reported as it was): into `costs` as a new world or a
            replay by the map the worker's world showed before, which it shows now."""
            map_id = maps_of.get(unit_in[slot].scenario_id, unit_in[slot].scenario_id)
            new_world = None if pid not in worker_maps else worker_maps[pid] != map_id
            costs.add_setup(seconds, new_world)
            worker_maps[pid] = map_id

        def measured(result: JobResult) -> None:
            """The unit's frames into `costs` (its set-up came as it ended)."""
            for began, ended, _, setup, first, frames in result.spans:
                costs.add_unit(ended - began, setup, first, frames)

        def merge(scenario_id: str) -> None:
            running[writers.submit(tracker.write_log, scenario_id)] = scenario_id

        def unit_ended(slot: int, result: JobResult) -> None:
            """A unit's result taken in once (sent as it ended, or with its job's): measured,
            and its clip's log written if it was the clip's last unit, else appended to."""
            if slot in ended:
                return
            ended.add(slot)
            unit = unit_in[slot]
            measured(result)
            if (clip := tracker.finished(unit, result)) is not None:
                merge(clip)
            elif tracker.appends(unit, result):
                writers.submit(tracker.append, unit.scenario_id)  # never raises

        tail = False  # nothing left to hand out or split: the workers give their contexts back

        def hand_out() -> None:
            nonlocal tail
            if tail:
                return
            busy = sum(not isinstance(j, str) for j in running.values())
            while waiting and busy < 2 * workers:
                submit(waiting.popleft())
                busy += 1
            while len(idle_maps) > max(0, workers - busy):
                idle_maps.popleft()  # those workers took queued jobs
            while not waiting and busy < workers and split_one():
                busy += 1
            if not waiting and busy < workers:  # a worker is idle and nothing is left to split
                tail = True
                for _ in range(workers):  # one each (`_give_back`): idle ones now, others next
                    running[pool.submit(_give_back, workers)] = ()  # a job of no units

        for scenario_id in tracker.ready:
            merge(scenario_id)
        hand_out()
        exiting = False  # the workers told to exit
        while running:
            done, _ = wait(set(running), timeout=0.1, return_when=FIRST_COMPLETED)
            _drain(frames_done, tick)
            for slot, pid, seconds in _queued(setups_done):  # worlds as they are set up
                set_up(slot, pid, seconds)
            for slot, result in _queued(units_done):  # (slot, JobResult) as units end
                unit_ended(slot, result)
            for future in done:
                job = running.pop(future)
                taken = slots.pop(future, ())
                if isinstance(job, str):
                    tracker.merged(job, future.result())  # merge_clip never raises
                    continue
                try:
                    results = future.result()
                except BrokenProcessPool:  # units that ended before it keep their results
                    results = [
                        JobResult(unit.scenario_id, "failed", error="the worker process died")
                        for unit in job
                    ]
                world = None  # the map of the world the job's worker holds now
                for unit, slot, result in zip(job, taken, results, strict=True):
                    unit_ended(slot, result)
                    if result.stage_seconds.get("setup"):
                        world = maps_of.get(unit.scenario_id)
                idle_maps.append(world)
            hand_out()
            if not exiting and not waiting and all(isinstance(j, str) for j in running.values()):
                # only logs left to write: the workers exit meanwhile (32 workers on an H100
                # host took 1.3 s to, after the last logs had taken 1.4 s to write). Once: the
                # pool's thread holds its lock while it waits for the workers
                pool.shutdown(wait=False)
                exiting = True
        _drain(frames_done, tick)
        if not exiting:
            pool.shutdown(wait=False)  # the workers exit while `then` runs
        if then is not None:
            then()


@contextmanager
def _removed_after(folder: Path) -> Iterator[None]:
    """Delete `folder` and what is in it on the way out, however the block ends."""
    try:
        yield
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _queued(reports: multiprocessing.Queue) -> list:
    """Everything the workers put on `reports` since the last call (without waiting)."""
    items = []
    while True:
        try:
            items.append(reports.get_nowait())
        except queue.Empty:
            return items


def _drain(frames_done: multiprocessing.Queue, tick: Callable[[int], None] | None) -> None:
    count = sum(_queued(frames_done))
    if tick is not None and count:
        tick(count)


def _run_ray(
    root: Path,
    jobs: list[Job],
    options: CollectOptions,
    tracker: _ClipTracker,
    tick: Callable[[int], None] | None,
    gpus: tuple[int, ...] = (),
) -> None:
    for scenario_id in tracker.ready:  # logs a stopped run left unwritten: written here
        tracker.merge(scenario_id)
    if not jobs:
        return
    import ray

    remote_job = ray.remote(num_cpus=1)(_ray_job).options(runtime_env={"env_vars": WORKER_THREADS})
    pending = {remote_job.remote(root, job, options, gpus): job for job in jobs}
    try:
        _gather_ray(ray, pending, tracker, tick)
    except KeyboardInterrupt:
        for reference in pending:
            ray.cancel(reference, force=True)
        raise


def _start_ray() -> int:
    """Joins the Ray cluster that RAY_ADDRESS names (or starts a local one of its own); returns
    its CPUs, the task slots the units are planned for. Without RAY_ADDRESS, Ray's own default
    joins whatever local cluster another process started last on this machine (its address
    file under /tmp/ray), and a run then failed when that process shut its cluster down ("the
    task's local raylet died"; seen with two commands at once): hence "local"."""
    try:
        import ray
    except ImportError:
        raise DriveE2EError("--backend ray needs Ray: pip install 'drivee2e-data[ray]'") from None
    address = os.environ.get("RAY_ADDRESS") or "local"
    ray.init(address=address, ignore_reinit_error=True, log_to_driver=False)
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def _ray_job(
    root: Path, job: Job, options: CollectOptions, gpus: tuple[int, ...]
) -> list[JobResult]:
    """A job's units in a Ray worker process: its GL context on a GPU chosen by the process id
    (Ray numbers no workers; the context is made once, at the process's first render)."""
    import ray

    egl_devices.use_device(egl_devices.device_for_worker(os.getpid(), gpus))
    node = ray.get_runtime_context().get_node_id()
    results = []
    for unit in job:
        result = run_unit(root, unit, options)
        result.node_frames = {node: result.frames}
        results.append(result)
    return results


def _gather_ray(
    ray: Any,
    pending: dict[Any, Job],
    tracker: _ClipTracker,
    tick: Callable[[int], None] | None,
) -> None:
    """Results as tasks finish; a clip's log is written here from its segments (the data root
    is on storage every node and this process share)."""
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        for reference in done:
            job = pending.pop(reference)
            try:
                results = ray.get(reference)
            except Exception as error:  # a task lost with its node
                results = [
                    JobResult(u.scenario_id, "failed", error=f"Ray task failed: {error}")
                    for u in job
                ]
            for unit, result in zip(job, results, strict=True):
                if tick is not None:
                    tick(result.frames)
                merge = tracker.finished(unit, result)
                if merge is not None:
                    tracker.merge(merge)


def index_rows(
    root: Path, path: Path, clip: tuple[Scenario, EgoMotion] | None = None
) -> dict[str, list] | None:
    """One log's rows of `logs/index.parquet` (see `write_index`), by column; None for a log
    that does not read or no longer matches its scenario. `clip`: the scenario and ego motion
    the log was just written from, where known (else read)."""
    try:
        with LogReader(path) as log:
            frames = list(log.sensor_frames)
    except LogFormatError:
        return None  # not ours to index; `drivee2e logs --validate` names what is wrong
    try:
        if clip is None:
            scenario = store.read_scenario(root, path.stem, require_map=False)
            clip = scenario, ego_motion(scenario)
        scenario, motion = clip
    except (DriveE2EError, ValueError):
        return None  # the log outlived or no longer matches its scenario: nothing to index
    behavior = scenario.behavior
    each = len(frames)
    return {
        "scenario_id": [scenario.scenario_id] * each,
        "map_id": [scenario.map_id] * each,
        "frame": frames,
        "t_ns": [int(scenario.t_ns[f]) for f in frames],
        "x_m": [float(motion.x_m[f]) for f in frames],
        "y_m": [float(motion.y_m[f]) for f in frames],
        "yaw_rad": [float(motion.yaw_rad[f]) for f in frames],
        "speed_mps": [float(motion.speed_mps[f]) for f in frames],
        "command": [int(motion.command[f]) for f in frames],
        "sub_scenario": [behavior.sub_scenario.value if behavior else None] * each,
        "category": [behavior.category.value if behavior else None] * each,
        "weather": [scenario.conditions.weather.value] * each,
        "time_of_day": [scenario.conditions.time_of_day.value] * each,
        "source": [scenario.source] * each,
    }


def write_index(root: Path, known: dict[str, dict[str, list]] | None = None) -> int:
    """`logs/index.parquet`: one row per sensor frame (every frame at 10 Hz) of every finished
    log (scenario, frame, t_ns, ego pose at the rear axle, speed, command, behaviour and
    conditions); returns rows. `known`: rows already made of some logs (`index_rows`, by
    scenario id), as a pool makes them while it collects."""
    root = Path(root)
    known = known or {}
    columns: dict[str, list] = {name: [] for name in INDEX_SCHEMA.names}
    for path in sorted((root / LOGS_FOLDER).glob("*.mcap")):
        rows = known.get(path.stem) or index_rows(root, path)
        if rows is None:
            continue
        for name, values in rows.items():
            columns[name].extend(values)
    table = pa.Table.from_arrays(
        [store.arrow_column(columns[field.name], field.type) for field in INDEX_SCHEMA],
        schema=INDEX_SCHEMA,
    )
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
