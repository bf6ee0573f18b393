"""Work smaller than a set of clips: the set's frames laid end to end and cut into one equal job
per worker (`plan_jobs`), so a job is a run of pieces of clips. A piece that is not a whole clip
is a segment. The segment that begins a clip is its log's head: the log's own bytes so far,
written by `LogWriter` as a single worker writes them, left without its summary (`_write_head`).
A later segment is a segment file of finished (compressed, indexed) MCAP chunks. The clip's log
is the head with the later segments' chunks appended as they finish (`SegmentedLog`), and its
summary once all are there. The log is byte for byte the one a single worker writes for the
clip: the same chunks (`FrameEncoder.encode`) in the same order, and a frame's capture depends
on nothing but the frame (`SensorSuite.capture` poses the world from the log).

Segment files live in `logs/.segments/<scenario_id>/<start>-<stop>.segment`, written under a
temporary name and renamed when whole, so a crash keeps every finished segment and a rerun
collects only the frames no segment holds. A segment file is never flushed to disk: its bytes
are copied into the log within seconds and the file deleted, so the disk need never write them
(it wrote every one twice, and 32 workers ending together waited on it). A process that dies
leaves the system's copy whole; only a machine that stops may leave a segment cut short or
with holes, which a rerun finds by the CRC-32 of its frames (`intact`) and collects again. The
log, heads included, is flushed before it is made final.

A head is `<start>-<stop>.head` beside its sidecar `<start>-<stop>.head.json` (its header and
the writer's state, `LogWriter.suspend`), written last: a head without one is unfinished. A
segment records the options it was made with and what its frames' bytes are
(`FRAME_BYTES_VERSION`); one made with other options, or by code whose frames were other bytes,
is dropped.

A segment may end before the frames it was planned for: a worker that ran out of work takes
the rest of a running segment (`runner._run_pool` moves its `stop`, `claim` below), so its
frames are known only at its end.

File layout: `MAGIC`, then per frame its number, time and chunks (each its length and bytes: a
chunk record and its message indexes, as they go into the log), then the JSON header
(scenario, first frame and the one after the last, options, the log's collection and label
records, the CRC-32 of the bytes from `MAGIC`'s end to the header), its length and `END`.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import os
import shutil
import struct
import threading
import time
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from drivee2e_data import __version__, store
from drivee2e_data.collect.job import (
    LOGS_FOLDER,
    ClipSetup,
    CollectOptions,
    JobResult,
    capture_frames,
    log_path,
    log_writer,
    open_clip,
    run_job,
)
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.logs.chunks import read_chunk
from drivee2e_data.logs.writer import EncodedFrame, FrameEncoder, LogWriter, label_kinds
from drivee2e_data.scenario import Scenario
from drivee2e_data.sensors.ego_state import EgoMotion, ego_motion
from drivee2e_data.sensors.suite import configured_rig

SEGMENTS_FOLDER = ".segments"
SUFFIX = ".segment"
TEMPORARY_SUFFIX = ".segment-tmp"
HEAD_SUFFIX = ".head"  # a clip's first segment: its log's head (`_write_head`)
SIDECAR_SUFFIX = ".json"  # beside a head: its header and the log writer's state
# 3: its frames' CRC-32 in the header; 2 (flushed, no CRC) and 1 (raw messages) are collected again
MAGIC, END = b"DE2ESEG3", b"END!"
# a unit's fixed cost is setting up its clip's world (0.4-1 s here, 1.9 s on a loaded H100
# host, docs/benchmarks.md) against 0.1-0.5 s a sensor frame per worker: no worker's share of a
# set is made shorter than this many sensor frames (at `--sensor-hz 2`, five times the frames)
MIN_SEGMENT_FRAMES = 25
# a cut within this many sensor frames of a clip's end moves to that end: a piece so short
# would cost a world's set-up for a second or less of work
MIN_PIECE_SENSOR_FRAMES = 5

_FRAME = struct.Struct("<IqI")  # frame, t_ns, chunks
_CHUNK = struct.Struct("<Q")  # a chunk's bytes
_TRAILER = struct.Struct("<I4s")  # the header's bytes (it comes just before), END
_CHECK_BLOCK = 1 << 22  # bytes read at a time by `intact`


@dataclass(frozen=True)
class WorkUnit:
    """Frames `start` to `stop - 1` of a clip; `whole` when that is the whole clip and no
    segment exists (the unit then writes the log itself)."""

    scenario_id: str
    start: int
    stop: int
    whole: bool = False

    @property
    def frames(self) -> int:
        return self.stop - self.start

    @property
    def name(self) -> str:
        return f"{self.start:06d}-{self.stop:06d}"


Job = tuple[WorkUnit, ...]  # units one worker runs in order


def shortest_unit(sensor_every: int = 1) -> int:
    """The fewest frames a worker's share holds with sensors at every `sensor_every`-th
    frame: `MIN_SEGMENT_FRAMES` sensor frames."""
    return MIN_SEGMENT_FRAMES * sensor_every


def plan_jobs(
    clip_frames: dict[str, int],
    covered: dict[str, list[tuple[int, int]]],
    workers: int,
    maps: dict[str, str] | None = None,
    sensor_every: int = 1,
    whole_clips: bool = True,
) -> list[Job]:
    """The work for clips of `clip_frames` (scenario id -> frames to collect) of which the
    frame ranges in `covered` are already in segment files, as one job per worker.

    Every frame not covered is laid end to end, clips on one map next to each other (in the
    order the maps first appear, then the clips' order: a worker going on to the next clip
    of its map keeps its twin, `sim.world.world_for`), and cut into `workers` runs of equal
    length (no more runs than `shortest_unit`s in the frames). A job is its run's
    pieces of clips, in order; cuts fall on sensor frames, and a cut within
    `MIN_PIECE_SENSOR_FRAMES` sensor frames of a clip's end moves to that end. A job runs its
    longest unit last (`_longest_last`). Jobs come longest first.

    One job per worker rather than many small units handed out as workers free up: each unit
    costs a world's set-up and a wait for the next, and with a few units a worker the last
    ones leave workers idle (at `--sensor-hz 2` the pool's wall time was 1.29x its even share,
    docs/benchmarks.md). With one worker each clip is its own job, whole clips written
    straight into their logs. `whole_clips=False`: every piece a segment, even a whole clip,
    so that any running piece can be split (`runner._run_pool`)."""
    gaps = {s: uncovered(n, covered.get(s, [])) for s, n in clip_frames.items()}
    maps = maps or {}
    rank: dict[str, int] = {}
    for scenario_id in clip_frames:
        rank.setdefault(maps.get(scenario_id, scenario_id), len(rank))
    order = sorted(clip_frames, key=lambda s: rank[maps.get(s, s)])  # stable: clip order kept
    pieces = [(s, a, b) for s in order for a, b in gaps[s]]
    total = sum(b - a for _, a, b in pieces)
    count = max(1, min(workers, math.ceil(total / shortest_unit(sensor_every))))
    if count == 1 and workers <= 1:
        return [
            (WorkUnit(s, a, b, whole=(a, b) == (0, clip_frames[s])),)
            for s, a, b in sorted(pieces, key=lambda p: p[1] - p[2])  # longest first
        ]
    cuts = _snapped_cuts(pieces, count, sensor_every)
    jobs: list[list[WorkUnit]] = [[]]
    offset = 0  # frames laid down before this piece
    for scenario_id, start, stop in pieces:
        position = start
        while cuts and cuts[0] < offset + stop - start:
            at = start + cuts.pop(0) - offset
            if at > position:
                jobs[-1].append(WorkUnit(scenario_id, position, at))
                position = at
            jobs.append([])
        if position < stop:
            jobs[-1].append(WorkUnit(scenario_id, position, stop))
        offset += stop - start
        if cuts and cuts[0] == offset:  # a cut between pieces
            cuts.pop(0)
            jobs.append([])
    # a piece from frame 0 to the clip's end is the clip's only piece, with no segment before it
    planned = [
        tuple(
            dataclasses.replace(
                u, whole=whole_clips and (u.start, u.stop) == (0, clip_frames[u.scenario_id])
            )
            for u in job
        )
        for job in jobs
        if job
    ]
    planned = [_longest_last(job, maps) for job in planned]
    return sorted(planned, key=lambda job: -sum(u.frames for u in job))  # stable


def _longest_last(job: Job, maps: dict[str, str]) -> Job:
    """The job's units with its longest last, the units of each map still together (the map of
    the longest unit's last): an idle worker can split a running unit in halves but takes one
    not begun whole, so a short unit at a job's end held the end of a 2 Hz run (its worker's
    set-up and seven sensor frames, on an H100 host, docs/benchmarks.md, "twelfth session")."""
    if len(job) < 2:
        return job
    most = max(u.frames for u in job)
    longest = next(u for u in reversed(job) if u.frames == most)  # the last of the longest
    by_map: dict[str, list[WorkUnit]] = {}
    for unit in job:
        by_map.setdefault(maps.get(unit.scenario_id, unit.scenario_id), []).append(unit)
    groups = list(by_map.values())
    last = next(g for g in groups if longest in g)
    last.remove(longest)
    return (*(u for g in groups if g is not last for u in g), *last, longest)


def _snapped_cuts(pieces: list[tuple[str, int, int]], count: int, sensor_every: int) -> list[int]:
    """Where `pieces` (scenario id, start, stop) laid end to end are cut into `count` runs of
    equal length: positions in frames from the first piece's start, each on a sensor frame and
    moved to its piece's end when within `MIN_PIECE_SENSOR_FRAMES` sensor frames of it."""
    total = sum(b - a for _, a, b in pieces)
    snap = MIN_PIECE_SENSOR_FRAMES * sensor_every
    cuts, offset, targets = set(), 0, [round(k * total / count) for k in range(1, count)]
    for _, start, stop in pieces:
        for target in targets:
            if not offset <= target < offset + stop - start:
                continue
            at = min(
                stop, max(start, round((start + target - offset) / sensor_every) * sensor_every)
            )
            if at - start < snap:
                at = start
            elif stop - at < snap:
                at = stop
            cuts.add(offset + at - start)
        offset += stop - start
    return sorted(cuts - {0, total})


def uncovered(frames: int, ranges: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """The parts of `range(frames)` no range of `ranges` holds, in order."""
    gaps, position = [], 0
    for start, stop in sorted(ranges):
        if start > position:
            gaps.append((position, min(start, frames)))
        position = max(position, stop)
    if position < frames:
        gaps.append((position, frames))
    return [(a, b) for a, b in gaps if b > a]


# what a captured frame's bytes are, by the code that captures them: raised with each change
# that makes them other bytes, so that heads and segments an earlier version left are collected
# again rather than joined with this version's frames into one log. 2: LiDAR points on a grid
# (`sensors.lidar.on_grid`, 2026-11-27)
FRAME_BYTES_VERSION = 2


def fingerprint(options: CollectOptions) -> str:
    """What a segment's frames depend on: the options (but how many frames: a frame is the same
    whatever the clip's length collected) and the version that made them."""
    fields = dataclasses.asdict(options)
    fields.pop("max_frames")
    made_by = {"version": __version__, "frame_bytes": FRAME_BYTES_VERSION}
    return json.dumps({**made_by, **fields}, sort_keys=True, default=list)


def segments_dir(root: Path, scenario_id: str) -> Path:
    return Path(root) / LOGS_FOLDER / SEGMENTS_FOLDER / scenario_id


def finished_segments(
    root: Path, scenario_id: str, options: CollectOptions
) -> list[tuple[Path, dict]]:
    """The clip's whole segment files and heads made with `options` and their headers (`start`,
    `stop`, the log's records; a head's also its writer's state under "head"), by first frame;
    others (made with other options, or unreadable) are deleted, since nothing can use them. A
    head without its sidecar is not yet whole, and left alone (`remove_temporary`)."""
    folder = segments_dir(root, scenario_id)
    if not folder.is_dir():
        return []
    kept = []
    wanted = fingerprint(options)
    for path in sorted(folder.glob(f"*{SUFFIX}")):
        try:
            header = read_header(path)
        except DriveE2EError:
            header = None
        if header is None or header["fingerprint"] != wanted:
            path.unlink()
            continue
        kept.append((path, header))
    for sidecar in sorted(folder.glob(f"*{HEAD_SUFFIX}{SIDECAR_SUFFIX}")):
        head = sidecar.with_name(sidecar.name.removesuffix(SIDECAR_SUFFIX))
        try:
            header = json.loads(sidecar.read_text())
            whole = head.stat().st_size >= header["head"]["data_end"]
        except (OSError, ValueError, KeyError, TypeError):
            header, whole = None, False
        if header is None or not whole or header["fingerprint"] != wanted:
            discard(head)
            continue
        kept.append((head, header))
    return sorted(kept, key=lambda found: found[1]["start"])


def discard(path: Path) -> None:
    """Delete a segment file, or a head and its sidecar."""
    path.unlink(missing_ok=True)
    if path.name.endswith(HEAD_SUFFIX):
        path.with_name(path.name + SIDECAR_SUFFIX).unlink(missing_ok=True)


def remove_temporary(root: Path) -> None:
    """A crashed or stopped run's unfinished segment files and heads (their frames are
    collected again)."""
    folders = Path(root) / LOGS_FOLDER / SEGMENTS_FOLDER
    for path in folders.glob(f"*/*{TEMPORARY_SUFFIX}"):
        path.unlink()
    for head in folders.glob(f"*/*{HEAD_SUFFIX}"):
        if not head.with_name(head.name + SIDECAR_SUFFIX).exists():
            head.unlink()


# ---------------------------------------------------------------------------- the file format


def _write_frame(stream: BinaryIO, encoded: EncodedFrame, crc: int) -> int:
    """Write one frame's record; returns `crc` (the CRC-32 of the frames before) carried on
    over its bytes."""
    for data in _frame_parts(encoded):
        stream.write(data)
        crc = zlib.crc32(data, crc)
    return crc


def _frame_parts(encoded: EncodedFrame) -> Iterator[bytes]:
    yield _FRAME.pack(encoded.frame, encoded.t_ns, len(encoded.chunks))
    for chunk in encoded.chunks:
        yield _CHUNK.pack(len(chunk.data))
        yield chunk.data


def _read_exactly(stream: BinaryIO, size: int, path: Path) -> bytes:
    data = stream.read(size)
    if len(data) != size:
        raise DriveE2EError(f"{path}: segment file ends early (expected {size} more bytes)")
    return data


def read_header(path: Path) -> dict:
    """A segment file's header (scenario, `start`, `stop`, options, the log's records), from
    the trailer at its end."""
    with open(path, "rb") as stream:
        if stream.read(len(MAGIC)) != MAGIC:
            raise DriveE2EError(f"{path}: not a drivee2e segment file")
        stream.seek(0, os.SEEK_END)
        end = stream.tell()
        if end < len(MAGIC) + _TRAILER.size:
            raise DriveE2EError(f"{path}: segment file ends early (no trailer)")
        stream.seek(end - _TRAILER.size)
        size, marker = _TRAILER.unpack(stream.read(_TRAILER.size))
        if marker != END or size > end - len(MAGIC) - _TRAILER.size:
            raise DriveE2EError(f"{path}: segment file has no end marker")
        stream.seek(end - _TRAILER.size - size)
        return json.loads(stream.read(size))


def intact(path: Path, header: dict) -> bool:
    """Whether a segment file's frames are the bytes it was written with (the CRC-32 its
    `header` records): false for one a stopped machine left with holes or stale blocks."""
    with open(path, "rb") as stream:
        stream.seek(-_TRAILER.size, os.SEEK_END)
        size, _ = _TRAILER.unpack(stream.read(_TRAILER.size))
        left = stream.tell() - _TRAILER.size - size - len(MAGIC)
        stream.seek(len(MAGIC))
        crc = 0
        while left > 0:
            block = stream.read(min(left, _CHECK_BLOCK))
            if not block:
                return False
            crc = zlib.crc32(block, crc)
            left -= len(block)
    return crc == header.get("crc32")


def read_frames(path: Path, header: dict | None = None) -> Iterator[EncodedFrame]:
    """The encoded frames of a segment file, in order, their chunks read back from their bytes
    (never inflated); `header`: the file's, where the caller has read it (`read_header`)."""
    if header is None:
        header = read_header(path)
    with open(path, "rb") as stream:
        stream.seek(len(MAGIC))
        for _ in range(header["stop"] - header["start"]):
            frame, t_ns, count = _FRAME.unpack(_read_exactly(stream, _FRAME.size, path))
            chunks = []
            for k in range(count):
                (size,) = _CHUNK.unpack(_read_exactly(stream, _CHUNK.size, path))
                data = _read_exactly(stream, size, path)
                chunks.append(read_chunk(data, f"{path}: frame {frame}, chunk {k}"))
            yield EncodedFrame(frame, t_ns, tuple(chunks))


# ---------------------------------------------------------------------------- the two jobs


def collect_segment(
    root: Path,
    unit: WorkUnit,
    options: CollectOptions,
    on_frame: Callable[[int], None] | None = None,
    claim: Callable[[int], bool] | None = None,
    on_setup: Callable[[float], None] | None = None,
) -> JobResult:
    """Capture a unit's frames into its segment file (never raises for a bad clip: see
    `job.run_job`). `claim(frame)` is asked before each frame: False ends the segment there
    (another worker took the rest); the file is named for the frames it holds, and none is
    written when the first frame is refused. `on_setup(seconds)` is told what its world's
    set-up took, once it is done."""
    if unit.whole:
        raise ValueError(f"{unit.scenario_id}: a whole-clip unit writes its log directly")
    folder = segments_dir(root, unit.scenario_id)

    def claimed() -> Iterator[int]:
        for frame in range(unit.start, unit.stop):
            if claim is not None and not claim(frame):
                return
            yield frame

    def work(result: JobResult) -> None:
        result.status = "collected"
        frames = claimed()
        first = next(frames, None)
        if first is None:
            return  # all taken before it began: nothing to set up
        setup = open_clip(
            root, unit.scenario_id, options, range(unit.start, unit.stop), result.stage_seconds
        )
        if on_setup is not None:
            on_setup(result.stage_seconds["setup"])
        result.renderer = setup.world.renderer
        folder.mkdir(parents=True, exist_ok=True)
        header = {
            "scenario_id": unit.scenario_id,
            "start": unit.start,
            "fingerprint": fingerprint(options),
            "collection": setup.collection,
            "labels": setup.labels,
        }
        frames_left = itertools.chain([first], frames)

        def capture(encode: Callable) -> int:
            seconds, every = result.stage_seconds, options.sensor_every
            return capture_frames(setup, frames_left, seconds, encode, on_frame, every)

        # the clip's first frames become its log's head; later ones a segment file
        piece = _Piece(Path(root), unit, setup, options, header, capture)
        result.frames = _write_head(piece) if unit.start == 0 else _write_segment(piece)

    return run_job(unit.scenario_id, work, unit.start)


@dataclass(frozen=True)
class _Piece:
    """A unit being collected: its clip's set-up, the options, its header so far (`stop` is
    added once its frames are known) and `capture(encode)`, which captures its frames, handing
    each to `encode`, and returns how many."""

    root: Path
    unit: WorkUnit
    setup: ClipSetup
    options: CollectOptions
    header: dict
    capture: Callable[[Callable], int]


def _write_segment(piece: _Piece) -> int:
    """Capture the piece's frames into a segment file named for the frames it holds; returns
    how many."""
    setup, unit, header = piece.setup, piece.unit, piece.header
    folder = segments_dir(piece.root, unit.scenario_id)
    encoder = FrameEncoder(
        setup.world.scenario,
        setup.world.intersection_map,
        setup.suite.rig,
        setup.suite.motion,
        camera_label_kinds=label_kinds(setup.labels),
    )
    temporary = folder / f"{unit.name}.{os.getpid()}{TEMPORARY_SUFFIX}"
    crc = 0
    try:
        with open(temporary, "wb") as stream:
            stream.write(MAGIC)

            def write(frame) -> None:
                nonlocal crc
                crc = _write_frame(stream, encoder.encode(frame), crc)

            count = piece.capture(write)
            header["stop"], header["crc32"] = unit.start + count, crc
            data = json.dumps(header).encode()  # key order kept: the log's records keep theirs
            stream.write(data + _TRAILER.pack(len(data), END))
        # not flushed to disk (the module's docstring): copied into the log and deleted soon
        done = dataclasses.replace(unit, stop=header["stop"])
        os.replace(temporary, folder / f"{done.name}{SUFFIX}")
    finally:
        temporary.unlink(missing_ok=True)
    return count


def _write_head(piece: _Piece) -> int:
    """Capture the piece's frames (from the clip's first) as the head of the clip's log: the
    log's own bytes so far, written by `LogWriter` as a one-worker run writes them, moved into
    the clip's segment folder with its state in a sidecar (`HEAD_SUFFIX`, `SIDECAR_SUFFIX`), so
    that the log is finished by appending the later segments to it rather than by copying the
    head (a clip's first segment, often most of it, had been copied after the run's last
    frame). Returns how many frames it holds."""
    unit, header = piece.unit, piece.header
    writer = log_writer(log_path(piece.root, unit.scenario_id), piece.setup, piece.options)
    try:
        count = piece.capture(writer.write)
        header["stop"] = unit.start + count
        folder = segments_dir(piece.root, unit.scenario_id)
        head = folder / f"{dataclasses.replace(unit, stop=header['stop']).name}{HEAD_SUFFIX}"
        header["head"] = writer.suspend(head)
    except BaseException:
        writer.abort()
        raise
    sidecar = head.with_name(head.name + SIDECAR_SUFFIX)
    temporary = sidecar.with_name(f"{sidecar.name}.{os.getpid()}{TEMPORARY_SUFFIX}")
    with open(temporary, "w") as stream:
        json.dump(header, stream)
        stream.flush()
        os.fsync(stream.fileno())
    os.replace(temporary, sidecar)  # the head is finished once its sidecar is there
    return count


class SegmentedLog:
    """A clip's log written from its head and segment files as they finish. `append` resumes
    the head (`LogWriter.resume`) and copies the finished segments that continue the log, in
    frame order, onto it (the disk's writes started as it grows, `Writeback`, but not waited
    for); `finish` copies the rest, checks that frames 0 to `frames - 1` are there once each,
    flushes the log to disk and makes it final (the head moved to the log's name). A pool
    appends while its workers collect the clip's later frames, so the clip's end costs only
    what its last segments hold (the whole log had been copied after the run's last
    frame: 0.1-1 s a clip at 2 Hz on an H100 host, 2.6-2.9 s at 10 Hz). Calls from several
    threads take turns. Nothing is final before `finish`: a crash leaves the head with what was
    appended (cut off when it is resumed again) and the segments, which the next run reuses.
    Logs of segments without a head (an earlier version's) are written new: a partial file,
    deleted by the next run after a crash."""

    def __init__(self, root: Path, scenario_id: str, options: CollectOptions, frames: int) -> None:
        self.root, self.scenario_id, self.options = Path(root), scenario_id, options
        self.frames = frames
        self.folder = segments_dir(root, scenario_id)
        self._lock = threading.Lock()
        self._writer: LogWriter | None = None
        self._headers: list[dict] = []  # of the segments copied, in order
        self._failure: BaseException | None = None  # of an `append`, raised again by `finish`
        self._closed = False
        self._clip: tuple | None = None  # scenario, map, rig and ego motion (`_prepared`)
        self.seconds = 0.0  # spent appending

    @property
    def _next(self) -> int:
        return self._headers[-1]["stop"] if self._headers else 0

    def append(self) -> None:
        """Copy the finished segments that continue the log. Never raises (it runs beside the
        pool): a failure is kept, and `finish` reports it."""
        with self._lock:
            if self._closed or self._failure is not None:
                return
            start = time.perf_counter()
            try:
                self._prepared()  # read now, off the clip's end, even if nothing continues yet
                self._copy_ready()
            except Exception as error:  # reported by `finish`
                self._failure = error
                self._discard()
            self.seconds += time.perf_counter() - start

    def finish(self) -> JobResult:
        """Copy what is left and make the log final, then delete the segments; the result's
        frames are 0 (the segments' jobs counted them) and its time is the copying's, appends
        included."""

        def work(result: JobResult) -> None:
            if self._failure is not None:
                raise self._failure
            left = self._copy_ready()
            if self._next != self.frames or left:
                ranges = sorted([(h["start"], h["stop"]) for h in self._headers] + left)
                raise DriveE2EError(
                    f"{self.folder}: segments {ranges} do not hold frames 0-{self.frames - 1} "
                    "once each"
                )
            assert self._writer is not None  # frames > 0 were copied
            self._writer.finish()
            self._writer = None
            shutil.rmtree(self.folder)
            result.renderer = self._headers[0]["collection"]["renderer"]
            result.status = "collected"
            result.log_bytes = log_path(self.root, self.scenario_id).stat().st_size

        with self._lock:
            result = run_job(self.scenario_id, work)
            if result.status != "collected":
                self._discard()
            self._closed = True
            result.seconds += self.seconds
            return result

    def close(self) -> None:
        """Stop writing an unfinished log (its clip failed, or the run stopped): a new log's
        partial file is deleted; a head and the segments stay for a rerun."""
        with self._lock:
            self._discard()
            self._closed = True

    def _copy_ready(self) -> list[tuple[int, int]]:
        """Copy the finished segments that continue the log; returns the frames (start, stop)
        of those found that do not (yet)."""
        copied = {(h["start"], h["stop"]) for h in self._headers}  # by earlier calls
        found = {
            h["start"]: (path, h)
            for path, h in finished_segments(self.root, self.scenario_id, self.options)
            if (h["start"], h["stop"]) not in copied
        }
        while self._next < self.frames and self._next in found:
            path, header = found.pop(self._next)
            if _records(header) != _records(self._headers[0] if self._headers else header):
                raise DriveE2EError(
                    f"{self.folder}: segments made with different renderers or rigs; delete the "
                    "folder to collect the clip again"
                )
            if "head" in header:  # the log's own first frames: continued, not copied
                self._open(header, head=path)
            else:
                writer = self._writer or self._open(header)
                for encoded in read_frames(path, header):
                    writer.write_encoded(encoded)
            self._headers.append(header)
        return [(h["start"], h["stop"]) for _, h in found.values()]

    def scenario(self) -> tuple[Scenario, EgoMotion]:
        """The clip's scenario and ego motion, as its log was written from (read once)."""
        with self._lock:
            scenario, _, _, motion = self._prepared()
        return scenario, motion

    def _prepared(self) -> tuple:
        """The clip's scenario, map, rig and ego motion, read on first use (0.1 s and more a
        clip: the first `append` reads them, so the clip's end need not)."""
        if self._clip is None:
            scenario = store.read_scenario(self.root, self.scenario_id)
            self._clip = (scenario, store.read_map(self.root, scenario.map_id),
                          configured_rig(self.options.suite()), ego_motion(scenario))  # fmt: skip
        return self._clip

    def _open(self, header: dict, head: Path | None = None) -> LogWriter:
        """The log's writer: a new one from the first segment's records, or the `head`'s
        resumed."""
        clip = self._prepared()
        path, every = log_path(self.root, self.scenario_id), self.options.sensor_every
        if head is not None:
            self._writer = LogWriter.resume(
                head, path, header["head"], *clip, header["labels"], sensor_every=every
            )
        else:
            self._writer = LogWriter(
                path, *clip, header["collection"], header["labels"], sensor_every=every
            )
        return self._writer

    def _discard(self) -> None:
        if self._writer is not None:
            self._writer.abort()
            self._writer = None


def _records(header: dict) -> str:
    """A segment's log records (renderer, rig's labels), as one comparable string. Not the GL
    driver: a Ray cluster's nodes may hold different GPUs, whose segments still make one log
    (its record names the driver of its first segment)."""
    collection = {k: v for k, v in header["collection"].items() if k != "gl_driver"}
    return json.dumps([collection, header["labels"]], sort_keys=True)


def merge_clip(root: Path, scenario_id: str, options: CollectOptions, frames: int) -> JobResult:
    """Write the clip's log from its segment files (which must hold frames 0 to `frames - 1`),
    then delete them (`SegmentedLog.finish`)."""
    return SegmentedLog(root, scenario_id, options, frames).finish()
