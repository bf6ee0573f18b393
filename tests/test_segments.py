"""Work units smaller than a clip: the plan (known cuts, longest first, resume around finished
segments), the segment file, and the log written from segments, byte for byte the one a single
worker writes."""

from __future__ import annotations

import dataclasses
import itertools
import multiprocessing
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import LONG_CLIP_FRAMES, SMALL_COLLECT, copy_clips

from drivee2e_data import store
from drivee2e_data.cli import main
from drivee2e_data.collect import balance, host, runner, segments
from drivee2e_data.collect.job import CollectOptions, log_path
from drivee2e_data.collect.runner import collect, merge_threads
from drivee2e_data.collect.segments import WorkUnit, plan_jobs, uncovered
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.sim.egl_devices import device_for_worker, parse_gpus
from drivee2e_data.sim.gl_context import context_made

# what the CLI makes of SMALL_COLLECT on this machine (depth LiDAR where GL works)
SMALL = CollectOptions(image_size=(160, 90), jpeg_quality=80)


def _cli_options() -> CollectOptions:
    from drivee2e_data.collect.host import plan

    return dataclasses.replace(SMALL, lidar=plan(frames=LONG_CLIP_FRAMES).lidar)


def _spans(jobs: list[tuple[WorkUnit, ...]]) -> list[list[tuple[str, int, int, bool]]]:
    return [[(u.scenario_id, u.start, u.stop, u.whole) for u in job] for job in jobs]


def test_a_set_is_cut_into_one_equal_job_per_worker_longest_first():
    # 130 frames on 2 workers: the clips laid end to end and cut at frame 65; a job runs its
    # longest unit last (an idle worker can split it in halves, where it takes a unit whole)
    assert _spans(plan_jobs({"a": 100, "b": 30}, {}, workers=2)) == [
        [("a", 0, 65, False)],
        [("b", 0, 30, True), ("a", 65, 100, False)],
    ]
    # one worker: whole clips, longest first, written straight into their logs
    assert plan_jobs({"b": 30, "a": 100}, {}, workers=1) == [
        (WorkUnit("a", 0, 100, whole=True),),
        (WorkUnit("b", 0, 30, whole=True),),
    ]
    # 16 workers on 16 clips of 100 frames: the cuts fall between clips
    many = plan_jobs({f"c{k}": 100 for k in range(16)}, {}, workers=16)
    assert _spans(many) == [[(f"c{k}", 0, 100, True)] for k in range(16)]
    # no more jobs than 25-frame shares: 60 frames make 3 jobs, not 16
    assert [u.frames for (u,) in plan_jobs({"a": 60}, {}, workers=16)] == [20, 20, 20]


def test_cuts_fall_on_sensor_frames_and_never_leave_a_sliver():
    # 2 Hz: the cut at frame 202 of 403 moves to the keyframe at 200 (the longer job first)
    assert _spans(plan_jobs({"a": 303, "b": 100}, {}, workers=2, sensor_every=5)) == [
        [("b", 0, 100, True), ("a", 200, 303, False)],
        [("a", 0, 200, False)],
    ]
    # 10 Hz: a cut 1 frame before a clip's end moves to that end (no world set up for 1 frame)
    assert _spans(plan_jobs({"a": 103, "b": 100}, {}, workers=2)) == [
        [("a", 0, 103, True)],
        [("b", 0, 100, True)],
    ]
    # at 2 Hz a share is 25 sensor frames: 200 frames are two jobs for 16 workers
    assert _spans(plan_jobs({"a": 200}, {}, workers=16, sensor_every=5)) == [
        [("a", 0, 100, False)],
        [("a", 100, 200, False)],
    ]
    # the host plan counts the same way: no more workers than 25-sensor-frame shares
    assert host.plan(3200, cores=64, memory=512.0, gpu=False, renderer="tiny").workers == 64
    sparse = host.plan(3200, cores=64, memory=512.0, gpu=False, renderer="tiny", sensor_every=5)
    assert sparse.workers == 3200 // 125


def test_clips_of_one_map_are_laid_next_to_each_other():
    """Clips alternate between two maps; laid map by map, a worker going on to its next clip
    keeps its twin; a job's longest unit goes last with the units of its map."""
    frames = {"a": 30, "b": 30, "c": 30, "d": 30, "e": 60}
    maps = {"a": "m0", "b": "m1", "c": "m0", "d": "m1", "e": "m1"}
    assert _spans(plan_jobs(frames, {}, workers=2, maps=maps)) == [
        [("a", 0, 30, True), ("c", 0, 30, True), ("b", 0, 30, True)],
        [("d", 0, 30, True), ("e", 0, 60, True)],
    ]
    # the longest last, the units of one map together: not m0, m1, m0
    assert segments._longest_last(
        (WorkUnit("a", 0, 10), WorkUnit("c", 0, 50), WorkUnit("b", 0, 20)), maps
    ) == (WorkUnit("b", 0, 20), WorkUnit("a", 0, 10), WorkUnit("c", 0, 50))
    one = plan_jobs(frames, {}, workers=1, maps=maps)
    assert [u.scenario_id for (u,) in one] == ["e", "a", "c", "b", "d"]


def test_a_rerun_plans_only_the_frames_no_segment_holds():
    assert uncovered(100, [(50, 75), (0, 25)]) == [(25, 50), (75, 100)]
    assert uncovered(30, [(0, 30)]) == []
    assert uncovered(30, []) == [(0, 30)]
    jobs = plan_jobs({"a": 100, "b": 30}, {"a": [(0, 25), (50, 75)]}, workers=2)
    assert _spans(jobs) == [
        [("a", 75, 90, False), ("a", 25, 50, False)],
        [("a", 90, 100, False), ("b", 0, 30, True)],
    ]
    # a clip partly done is never whole again, even with one worker: its log comes from segments
    assert plan_jobs({"a": 100}, {"a": [(0, 25)]}, workers=1) == [(WorkUnit("a", 25, 100),)]


def test_gpus_are_dealt_round_robin():
    assert [device_for_worker(k, (0, 1)) for k in range(5)] == [0, 1, 0, 1, 0]
    assert device_for_worker(3, ()) is None
    assert parse_gpus("all") is None and parse_gpus("0,2") == (0, 2)
    for bad in ("0,0", "-1", "x", ""):
        with pytest.raises(ValueError, match="--gpus"):
            parse_gpus(bad)


@pytest.mark.slow
def test_a_log_from_segments_is_byte_identical_to_one_workers(
    collected_root: Path, synthetic_root: Path, tmp_path: Path
):
    """The first clip, 36 frames collected alone by `collected_root`; here three segments made
    in this process (the middle one first, as another worker might), then the log written: the
    first is the log's head (its bytes as the log begins, and a sidecar), the others are
    appended to it."""
    scenario_id = store.scenario_ids(synthetic_root)[0]
    root = copy_clips(synthetic_root, tmp_path / "data", [scenario_id])
    options = dataclasses.replace(_cli_options(), max_frames=LONG_CLIP_FRAMES)
    for start, stop in ((12, 24), (0, 12), (24, 36)):
        result = segments.collect_segment(root, WorkUnit(scenario_id, start, stop), options)
        assert (result.status, result.frames) == ("collected", stop - start), result.error
    folder = segments.segments_dir(root, scenario_id)
    assert sorted(p.name for p in folder.iterdir()) == [
        "000000-000012.head", "000000-000012.head.json", "000012-000024.segment",
        "000024-000036.segment",
    ]  # fmt: skip
    merged = segments.merge_clip(root, scenario_id, options, LONG_CLIP_FRAMES)
    assert merged.status == "collected", merged.error
    alone = collected_root / "logs" / f"{scenario_id}.mcap"
    assert (root / "logs" / f"{scenario_id}.mcap").read_bytes() == alone.read_bytes()
    assert not folder.exists()  # the segments go once the log is written


@pytest.mark.slow
def test_a_log_grows_from_its_head_as_its_segments_finish_and_ends_the_same_as_one_workers(
    collected_root: Path, synthetic_root: Path, tmp_path: Path, monkeypatch
):
    """The clip's first segment is its log's head, written as the log begins; a pool appends each
    finished segment that continues it (`SegmentedLog`): a segment that does not continue it
    waits; the head is grown in place, never copied; the finished log equals one worker's. The
    clip's scenario is read once, by the first append, not at the clip's end."""
    scenario_id = store.scenario_ids(synthetic_root)[0]
    root = copy_clips(synthetic_root, tmp_path / "data", [scenario_id])
    options = dataclasses.replace(_cli_options(), max_frames=LONG_CLIP_FRAMES)
    log = segments.SegmentedLog(root, scenario_id, options, LONG_CLIP_FRAMES)
    head = segments.segments_dir(root, scenario_id) / "000000-000012.head"
    reads = []
    read_scenario = store.read_scenario
    monkeypatch.setattr(
        store, "read_scenario", lambda *a, **k: reads.append(1) or read_scenario(*a, **k)
    )
    sizes, read_by_log = [], []
    for start, stop in ((24, 36), (0, 12), (12, 24)):
        assert segments.collect_segment(root, WorkUnit(scenario_id, start, stop), options).frames
        if start == 0:
            written = head.stat().st_size
        before = len(reads)
        log.append()
        read_by_log.append(len(reads) - before)
        sizes.append(head.stat().st_size if head.exists() else 0)
    assert read_by_log == [1, 0, 0]
    assert sizes[0] == 0  # frames 24-35 do not continue a log not begun
    assert sizes[1] == written  # the head is the log so far: nothing to copy
    assert sizes[2] > written  # frames 12-35 appended to it
    assert not list((root / "logs").glob(".*.partial"))  # no second copy of the log
    before = len(reads)
    result = log.finish()
    assert result.status == "collected", result.error
    assert len(reads) == before and log.scenario()[0].scenario_id == scenario_id
    alone = collected_root / "logs" / f"{scenario_id}.mcap"
    assert log_path(root, scenario_id).read_bytes() == alone.read_bytes()
    assert not segments.segments_dir(root, scenario_id).exists()


def test_a_failed_append_is_reported_when_the_log_is_finished_and_the_head_is_kept(
    collected_root: Path, synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    """An append runs beside the pool and never raises: its error fails the clip at `finish`,
    and no log is made. The head, grown by an append that was not finished, is cut back to its
    own frames when resumed again, and the log then equals one worker's."""
    scenario_id = store.scenario_ids(synthetic_root)[1]
    root = copy_clips(synthetic_root, tmp_path / "data", [scenario_id])
    options = dataclasses.replace(_cli_options(), max_frames=6)
    for start, stop in ((0, 3), (3, 6)):
        assert segments.collect_segment(root, WorkUnit(scenario_id, start, stop), options).frames
    head = segments.segments_dir(root, scenario_id) / "000000-000003.head"
    own = head.stat().st_size
    unfinished = segments.SegmentedLog(root, scenario_id, options, 6)
    unfinished.append()
    assert head.stat().st_size > own  # frames 3-5 appended
    unfinished.close()  # the run stopped: the head and the segments stay
    assert head.exists()

    def failing(path: Path, header: dict | None = None):  # type: ignore[no-untyped-def]
        raise OSError(f"{path}: the disk went away")

    with monkeypatch.context() as patched:
        patched.setattr(segments, "read_frames", failing)
        log = segments.SegmentedLog(root, scenario_id, options, 6)
        log.append()  # does not raise
        result = log.finish()
    assert result.status == "failed"
    assert result.error.startswith("OSError: ") and "the disk went away" in result.error
    assert not log_path(root, scenario_id).exists()
    assert head.stat().st_size == own  # cut back to the head's own frames
    assert len(segments.finished_segments(root, scenario_id, options)) == 2
    again = segments.SegmentedLog(root, scenario_id, options, 6).finish()
    assert again.status == "collected", again.error
    alone = collected_root / "logs" / f"{scenario_id}.mcap"
    assert log_path(root, scenario_id).read_bytes() == alone.read_bytes()


@pytest.mark.slow
def test_a_crashed_run_resumes_from_its_finished_segments(
    collected_root: Path, synthetic_root: Path, tmp_path: Path
):
    """A run that died after one segment (and mid-way through another) leaves a segment file and
    a temporary one; the rerun keeps the first, drops the second and a segment made with other
    options, collects the rest, and writes the same log as one worker."""
    scenario_id = store.scenario_ids(synthetic_root)[0]
    root = copy_clips(synthetic_root, tmp_path / "data", [scenario_id])
    options = dataclasses.replace(_cli_options(), max_frames=LONG_CLIP_FRAMES)
    assert segments.collect_segment(root, WorkUnit(scenario_id, 0, 20), options).frames == 20
    folder = segments.segments_dir(root, scenario_id)
    (folder / "000020-000036.4242.segment-tmp").write_bytes(b"DE2ESEG1 cut short")
    orphan = folder / "000000-000009.head"  # a head whose worker died before its sidecar
    orphan.write_bytes(b"\x89MCAP0\r\n cut short")
    segments.remove_temporary(root)
    assert sorted(p.name for p in folder.iterdir()) == ["000000-000020.head",
                                                        "000000-000020.head.json"]  # fmt: skip
    (folder / "000020-000036.4242.segment-tmp").write_bytes(b"DE2ESEG1 cut short")
    other = dataclasses.replace(options, jpeg_quality=50)
    assert segments.collect_segment(root, WorkUnit(scenario_id, 20, 28), other).frames == 8
    seen: list[int] = []

    def progress(total: int, clips: int):  # type: ignore[no-untyped-def]
        seen.append(total)
        return None

    summary = collect(root, options, workers=1, progress=progress)
    assert seen == [LONG_CLIP_FRAMES - 20]  # only the frames the kept segment lacks
    assert [(r.status, r.frames) for r in summary.results] == [("collected", 16)]
    alone = collected_root / "logs" / f"{scenario_id}.mcap"
    assert (root / "logs" / f"{scenario_id}.mcap").read_bytes() == alone.read_bytes()
    assert not (root / "logs" / segments.SEGMENTS_FOLDER).exists()


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="names open files through /proc")
def test_segment_files_are_never_flushed_to_disk_but_heads_and_logs_are(
    synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    """A segment is copied into its log and deleted within seconds: its bytes are never flushed
    (fsync), where the head (the log's own first frames) and the finished log are."""
    import os

    scenario_id = store.scenario_ids(synthetic_root)[1]
    root = copy_clips(synthetic_root, tmp_path / "data", [scenario_id])
    options = dataclasses.replace(_cli_options(), max_frames=6)
    flushed: list[str] = []
    real_fsync = os.fsync

    def fsync(fd: int) -> None:
        flushed.append(os.readlink(f"/proc/self/fd/{fd}"))
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    for start, stop in ((0, 3), (3, 6)):
        assert segments.collect_segment(root, WorkUnit(scenario_id, start, stop), options).frames
    assert segments.merge_clip(root, scenario_id, options, 6).status == "collected"
    names = [Path(path).name for path in flushed]
    assert not [name for name in names if ".segment" in name and ".head" not in name]
    assert any(name.startswith(".") and name.endswith(".partial") for name in names)  # the head
    assert any(".head.json" in name for name in names)  # its sidecar


def test_heads_and_segments_of_frames_made_other_bytes_by_an_earlier_version_are_dropped(
    synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    """A head and a segment captured by code whose frames were other bytes (an earlier
    `FRAME_BYTES_VERSION`) are not joined with this version's frames: the next run drops them."""
    scenario_id = store.scenario_ids(synthetic_root)[1]
    root = copy_clips(synthetic_root, tmp_path / "data", [scenario_id])
    options = dataclasses.replace(_cli_options(), max_frames=6)
    with monkeypatch.context() as earlier:
        earlier.setattr(segments, "FRAME_BYTES_VERSION", segments.FRAME_BYTES_VERSION - 1)
        for start, stop in ((0, 3), (3, 6)):
            unit = WorkUnit(scenario_id, start, stop)
            assert segments.collect_segment(root, unit, options).frames
        assert len(segments.finished_segments(root, scenario_id, options)) == 2
    assert segments.finished_segments(root, scenario_id, options) == []
    assert not list(segments.segments_dir(root, scenario_id).iterdir())


@pytest.mark.slow
def test_a_segment_a_stopped_machine_left_with_holes_is_collected_again(
    collected_root: Path, synthetic_root: Path, tmp_path: Path
):
    """Segment files are never flushed to disk (the module's docstring): one left with a run of
    zeros among its frames, its trailer whole, fails the CRC-32 its header keeps, and the rerun
    collects those frames again; the log equals one worker's."""
    scenario_id = store.scenario_ids(synthetic_root)[0]
    root = copy_clips(synthetic_root, tmp_path / "data", [scenario_id])
    options = dataclasses.replace(_cli_options(), max_frames=LONG_CLIP_FRAMES)
    for start, stop in ((0, 12), (12, 24), (24, 36)):
        assert segments.collect_segment(root, WorkUnit(scenario_id, start, stop), options).frames
    folder = segments.segments_dir(root, scenario_id)
    damaged, kept = folder / "000012-000024.segment", folder / "000024-000036.segment"
    header = segments.read_header(damaged)
    assert segments.intact(damaged, header) and segments.intact(kept, segments.read_header(kept))
    data = bytearray(damaged.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 4096] = bytes(4096)
    damaged.write_bytes(bytes(data))
    assert segments.read_header(damaged) == header  # its trailer reads as a whole file's
    assert not segments.intact(damaged, header)
    seen: list[int] = []

    def progress(total: int, clips: int):  # type: ignore[no-untyped-def]
        seen.append(total)
        return None

    summary = collect(root, options, workers=1, progress=progress)
    assert seen == [12]  # frames 12-23 again; the head and frames 24-35 kept
    assert [(r.status, r.frames) for r in summary.results] == [("collected", 12)]
    alone = collected_root / "logs" / f"{scenario_id}.mcap"
    assert (root / "logs" / f"{scenario_id}.mcap").read_bytes() == alone.read_bytes()


@pytest.mark.slow
@pytest.mark.parametrize("workers", [1, 2])
def test_a_run_stopped_between_its_last_segment_and_the_log_writes_the_log_on_rerun(
    collected_root: Path, synthetic_root: Path, tmp_path: Path, workers: int
):
    """Every segment of a clip was finished but the log not written (the run stopped in
    between): the rerun collects nothing and writes the log, the same as one worker's; a second
    rerun finds it done (and with two workers starts no pool for nothing)."""
    scenario_id = store.scenario_ids(synthetic_root)[0]
    root = copy_clips(synthetic_root, tmp_path / "data", [scenario_id])
    options = dataclasses.replace(_cli_options(), max_frames=LONG_CLIP_FRAMES)
    for start, stop in ((0, 18), (18, 36)):
        assert segments.collect_segment(root, WorkUnit(scenario_id, start, stop), options).frames
    seen: list[int] = []

    def progress(total: int, clips: int):  # type: ignore[no-untyped-def]
        seen.append(total)
        return None

    summary = collect(root, options, workers=workers, progress=progress)
    assert seen == [0]  # no frame left to collect
    assert [(r.scenario_id, r.status) for r in summary.results] == [(scenario_id, "collected")]
    alone = collected_root / "logs" / f"{scenario_id}.mcap"
    assert (root / "logs" / f"{scenario_id}.mcap").read_bytes() == alone.read_bytes()
    assert not (root / "logs" / segments.SEGMENTS_FOLDER).exists()
    again = collect(root, options, workers=workers)
    assert [r.status for r in again.results] == ["skipped"]


def test_segments_that_do_not_make_the_clip_are_a_clear_error(synthetic_root: Path, tmp_path: Path):
    scenario_id = store.scenario_ids(synthetic_root)[1]
    root = copy_clips(synthetic_root, tmp_path / "data", [scenario_id])
    options = dataclasses.replace(_cli_options(), max_frames=6)
    for start, stop in ((0, 3), (4, 6)):
        assert segments.collect_segment(root, WorkUnit(scenario_id, start, stop), options).frames
    result = segments.merge_clip(root, scenario_id, options, 6)
    assert result.status == "failed"
    assert "segments [(0, 3), (4, 6)] do not hold frames 0-5 once each" in result.error
    assert not (root / "logs" / f"{scenario_id}.mcap").exists()
    path = segments.segments_dir(root, scenario_id) / "000004-000006.segment"
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])  # cut short: not whole
    with pytest.raises(DriveE2EError, match=r"ends early|no end marker"):
        list(segments.read_frames(path))
    shutil.rmtree(segments.segments_dir(root, scenario_id))


@pytest.mark.slow
def test_a_pool_cuts_one_long_clip_across_its_workers(
    collected_root: Path, synthetic_root: Path, tmp_path: Path
):
    """`--workers 2` on one 36-frame clip: two 18-frame segments on two workers, one log, the
    same bytes as the one-worker log."""
    scenario_id = store.scenario_ids(synthetic_root)[0]
    root = copy_clips(synthetic_root, tmp_path / "data", [scenario_id])
    arguments = ["collect", str(root), "--max-frames", str(LONG_CLIP_FRAMES), "--workers", "2"]
    assert main([*arguments, *SMALL_COLLECT]) == 0
    alone = collected_root / "logs" / f"{scenario_id}.mcap"
    assert (root / "logs" / f"{scenario_id}.mcap").read_bytes() == alone.read_bytes()


def test_an_idle_worker_takes_the_later_half_of_a_running_unit():
    """Claims, as a pool's workers and parent share them: a worker claims each frame before
    capturing it; the parent gives an idle worker the later half of what is left, less a
    world's set-up, from a sensor frame on; all of a unit not begun; nothing when too little
    is left."""
    claims = runner._Claims(3)
    running = WorkUnit("a", 0, 100)
    slot = claims.add(running)
    assert all(runner._Claims.claim(claims.shared, slot, f) for f in range(10))
    # 90 left, a set-up of 3 frames: the thief takes from 10 + (90 + 3) // 2 = 56 on
    assert balance.SETUP_FRAMES == 3
    assert claims.left(slot, 1) == 90
    assert claims.split(slot, running, sensor_every=1) == WorkUnit("a", 56, 100)
    assert runner._Claims.claim(claims.shared, slot, 55)
    assert not runner._Claims.claim(claims.shared, slot, 56)
    # at 2 Hz the cut is on a sensor frame: 10 + (90 + 15) // 2 = 62, so 65
    sparse = claims.add(running)
    assert not claims.begun(sparse, running)
    runner._Claims.claim(claims.shared, sparse, 9)
    assert claims.begun(sparse, running)
    assert claims.left(sparse, 5) == 18  # frames 10, 15, .. 95
    assert claims.split(sparse, running, sensor_every=5) == WorkUnit("a", 65, 100)
    # a thief whose world shows the clip's map already pays only the actors (1 sensor frame):
    # 55 left, 10 + (55 + 5) // 2 = 40 on: 5 sensor frames
    assert balance.REPLAY_SETUP_FRAMES == 1
    assert claims.split(sparse, running, 5, balance.REPLAY_SETUP_FRAMES) == WorkUnit("a", 40, 65)
    # a unit not begun goes whole; then nothing is left to split
    waiting = WorkUnit("b", 40, 80)
    later = claims.add(waiting)
    assert claims.split(later, waiting, sensor_every=1) == WorkUnit("b", 40, 80)
    assert not runner._Claims.claim(claims.shared, later, 40)
    assert claims.split(later, waiting, sensor_every=1) is None
    assert claims.full
    with pytest.raises(RuntimeError, match="no slot"):
        claims.add(waiting)


def test_set_up_costs_are_measured_in_sensor_frames_once_a_kind_is_seen():
    """Until a kind of set-up has been seen, and a unit has ended, the constants stand; then the
    median set-up over the mean time of a sensor frame, a new world's first frames one sensor
    frame more; a worker's first world (None) is not counted, its unit's frames are."""
    costs = balance.SetupCosts(sensor_every=5)
    assert (costs.frames(new_world=True), costs.frames(new_world=False)) == (3, 1)
    costs.add_setup(1.0, new_world=True)  # reported as it ended: no frame time known yet
    assert costs.frames(new_world=True) == 3
    costs.add_setup(2.0, new_world=None)
    costs.add_unit(seconds=12.0, setup=2.0, first=0, frames=200)  # 40 sensor frames
    assert costs.frames(new_world=False) == 1
    costs.add_setup(0.25, new_world=False)
    costs.add_unit(seconds=4.25, setup=0.25, first=3, frames=80)  # 5, 10 .. 80: 16
    costs.add_setup(1.1, new_world=True)
    costs.add_setup(0.9, new_world=True)
    costs.add_unit(seconds=6.0, setup=0.9, first=0, frames=196)  # 40
    # 10 + 4 + 5.1 s of capture over 40 + 16 + 40 sensor frames: 0.199 s a sensor frame
    assert balance.sensor_frames(3, 80, 5) == 16
    assert costs.frames(new_world=False) == 2  # 0.25 / 0.199, rounded up
    assert costs.frames(new_world=True) == 6 + 1  # 1.0 / 0.199 -> 6, and the first frames


def test_an_idle_worker_takes_what_ends_a_job_soonest():
    """The taker's set-up counts: a unit on the map its world shows costs it a replay (1 sensor
    frame), another map's a new world (3); a begun unit gives half of what is left less that,
    a unit not begun goes whole where its worker would end it later than the taker."""
    maps = {"a": "m1", "b": "m2", "c": "m2"}
    costs = balance.SetupCosts(sensor_every=5)
    on_a = balance.Candidate(0, "a", left=12, begun=True)
    on_b = balance.Candidate(1, "b", left=12, begun=True)
    # on its own map the taker ends its worker's unit (12 - 1) // 2 = 5 sooner, on the other
    # (12 - 3) // 2 = 4
    assert balance.split_order([on_a, on_b], "m2", maps, costs) == [(on_b, 1), (on_a, 3)]
    assert balance.split_order([on_a, on_b], "m1", maps, costs) == [(on_a, 1), (on_b, 3)]
    # a fresh worker (no world yet) pays the new world everywhere: the most left first
    longer = balance.Candidate(1, "b", left=18, begun=True)
    assert balance.split_order([on_a, longer], None, maps, costs) == [(longer, 3), (on_a, 3)]
    # much more left elsewhere still wins over the cheaper set-up: (18 - 3) // 2 = 7 > 5
    assert balance.split_order([on_a, longer], "m1", maps, costs) == [(longer, 3), (on_a, 1)]
    # a unit not begun, 7 sensor frames, behind 1 frame of its worker's on the same map: its
    # worker ends it after 1 + 1 + 7 = 9, a taker on another map after 3 + 7 = 10: left alone;
    # a taker on its map ends it after 1 + 7 = 8, and its worker after 1
    behind = balance.Candidate(2, "c", left=7, begun=False, ahead=1, follows_its_map=True)
    assert balance.split_order([behind], "m1", maps, costs) == []
    assert balance.split_order([behind], "m2", maps, costs) == [(behind, 1)]
    # behind 12 frames, a taker on another map ends it after 12 against 12 + 1 + 7 = 20
    far = balance.Candidate(2, "c", left=7, begun=False, ahead=12, follows_its_map=True)
    assert balance.split_order([far, on_a], "m1", maps, costs) == [(far, 3), (on_a, 1)]


@pytest.mark.slow
def test_a_split_unit_still_gives_the_one_worker_log(
    collected_root: Path, synthetic_root: Path, tmp_path: Path, monkeypatch
):
    """Two workers given 32 and 4 of a clip's 36 frames: the one done first takes the later
    half of the other's frames (and half again of what is left, where it is done with those
    first too), and the log written from the segments is the one-worker log."""
    scenario_id = store.scenario_ids(synthetic_root)[0]
    root = copy_clips(synthetic_root, tmp_path / "data", [scenario_id])
    unequal = [(WorkUnit(scenario_id, 0, 32),), (WorkUnit(scenario_id, 32, LONG_CLIP_FRAMES),)]
    monkeypatch.setattr(segments, "plan_jobs", lambda *args, **kwargs: unequal)
    options = dataclasses.replace(_cli_options(), max_frames=LONG_CLIP_FRAMES)
    summary = collect(root, options, workers=2)
    (result,) = summary.results
    assert result.status == "collected" and result.frames == LONG_CLIP_FRAMES
    # the two planned units and one piece split off the first at least (how many more depends
    # on the two workers' pace: a busy machine has split it twice)
    assert len(result.spans) >= 3
    # each span names its piece's frames: together they tile the clip, none twice
    pieces = sorted((first, first + frames) for *_, first, frames in result.spans)
    assert pieces[0][0] == 0 and pieces[-1][1] == LONG_CLIP_FRAMES
    assert all(end == start for (_, end), (start, _) in itertools.pairwise(pieces))
    assert (32, LONG_CLIP_FRAMES) in pieces  # the second unit whole
    assert 0 < pieces[1][0] < 32 and pieces[-2][1] == 32  # the first unit's later frames split
    alone = collected_root / "logs" / f"{scenario_id}.mcap"
    assert (root / "logs" / f"{scenario_id}.mcap").read_bytes() == alone.read_bytes()


def test_a_two_node_ray_cluster_collects_one_clip_across_both(
    collected_root: Path, synthetic_root: Path, tmp_path: Path, capsys
):
    """Two Ray nodes on this machine (a raylet each, one CPU each): the 36-frame clip's two
    segments run one on each node, and the log written from them is the one-worker log."""
    ray = pytest.importorskip("ray", reason="the Ray backend needs the ray extra")
    from ray.cluster_utils import Cluster

    scenario_id = store.scenario_ids(synthetic_root)[0]
    root = copy_clips(synthetic_root, tmp_path / "data", [scenario_id])
    ray.shutdown()  # another test's local Ray
    cluster = Cluster(
        initialize_head=True, head_node_args={"num_cpus": 1, "resources": {"node_a": 1}}
    )
    try:
        cluster.add_node(num_cpus=1, resources={"node_b": 1})
        cluster.wait_for_nodes()
        ray.init(address=cluster.address, log_to_driver=False)
        arguments = ["collect", str(root), "--max-frames", str(LONG_CLIP_FRAMES)]
        assert main([*arguments, "--backend", "ray", *SMALL_COLLECT]) == 0
        nodes = {node["NodeID"][:8] for node in ray.nodes()}
    finally:
        ray.shutdown()
        cluster.shutdown()
    out = capsys.readouterr().out
    assert "workers: 2" in out  # the cluster's two CPUs, not --workers' default of 1
    shares = out.split("frames on each of 2 Ray nodes: ")[1].splitlines()[0]
    assert {share.split()[0] for share in shares.split(", ")} == nodes
    assert [share.split()[1] for share in shares.split(", ")] == ["18", "18"]
    alone = collected_root / "logs" / f"{scenario_id}.mcap"
    assert (root / "logs" / f"{scenario_id}.mcap").read_bytes() == alone.read_bytes()


def test_log_writing_threads_grow_with_the_pool_past_sixteen_workers():
    # two up to 16 workers (the 2-core machine, a 16-core host), one more per 8 past that, at
    # most 8
    assert [merge_threads(n) for n in (1, 2, 16, 23, 24, 32, 64, 128)] == [2, 2, 2, 2, 3, 4, 8, 8]


def test_pool_workers_make_their_gl_context_as_they_start(tmp_path):
    """Where worlds draw with the GL renderer a worker's context is made by its initialiser,
    before any job; not where the cameras are finished with CUDA (which must start first), nor
    for pybullet's renderers."""
    from drivee2e_data.processes import worker_pool
    from drivee2e_data.sim.gl_context import gl_available

    assert runner.context_at_start(CollectOptions())  # renderer "auto", CPU post-processing
    assert runner.context_at_start(CollectOptions(renderer="gl"))
    assert not runner.context_at_start(CollectOptions(renderer="gl", post_process="cuda"))
    assert not runner.context_at_start(CollectOptions(renderer="tiny"))
    if not gl_available():
        pytest.skip("no OpenGL context can be made here")
    context = runner.worker_context()
    for make_context in (True, False):
        initargs = (context.Queue(), context.Queue(), context.Queue(), context.Value("i", 0), (),
                    runner._Claims(1, context).shared, str(tmp_path), make_context)  # fmt: skip
        with worker_pool(1, runner._init_worker, initargs, context) as pool:
            assert pool.submit(context_made).result() is make_context


def test_pool_workers_make_their_gl_contexts_a_few_at_a_time(tmp_path):
    """A worker makes its context only with one of the pool's slots (`contexts_at_once`: a few
    per GPU): with none free it waits, and takes no job, until one is."""
    from drivee2e_data.processes import worker_pool
    from drivee2e_data.sim.egl_devices import CONTEXTS_AT_ONCE_PER_GPU, contexts_at_once
    from drivee2e_data.sim.gl_context import gl_available

    assert contexts_at_once(()) == CONTEXTS_AT_ONCE_PER_GPU
    assert contexts_at_once((0, 1)) == 2 * CONTEXTS_AT_ONCE_PER_GPU
    if not gl_available():
        pytest.skip("no OpenGL context can be made here")
    context = runner.worker_context()
    slots = context.Semaphore(0)  # none free yet
    initargs = (context.Queue(), context.Queue(), context.Queue(), context.Value("i", 0), (),
                runner._Claims(1, context).shared, str(tmp_path), True, slots)  # fmt: skip
    with worker_pool(1, runner._init_worker, initargs, context) as pool:
        job = pool.submit(context_made)
        time.sleep(1.0)
        assert not job.done()  # the worker waits for a slot
        slots.release()
        assert job.result(timeout=60) is True
    assert slots.acquire(timeout=5)  # given back once made


@pytest.mark.slow
def test_at_the_tail_each_worker_gives_its_gl_context_back_once(tmp_path):
    """`_give_back`, the pool's last job for each worker: the idle worker gives its context back
    at once and is held until the busy one has done the same after its job (so neither takes
    two); afterwards no worker holds a context."""
    from drivee2e_data.processes import worker_pool
    from drivee2e_data.sim.gl_context import gl_available

    if not gl_available():
        pytest.skip("no OpenGL context can be made here")
    context = runner.worker_context()
    given_back = (context.Value("i", 0), context.Event())
    initargs = (context.Queue(), context.Queue(), context.Queue(), context.Value("i", 0), (),
                runner._Claims(1, context).shared, str(tmp_path), True, None,
                given_back)  # fmt: skip
    with worker_pool(2, runner._init_worker, initargs, context) as pool:
        assert all(pool.submit(context_made).result() for _ in range(2))
        busy = pool.submit(time.sleep, 6.0)
        time.sleep(0.5)  # the other worker idle
        first, second = (pool.submit(runner._give_back, 2) for _ in range(2))
        deadline = time.monotonic() + 4.0
        while given_back[0].value < 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert given_back[0].value == 1 and not first.done() and not second.done()
        assert not busy.done()  # the second is the busy worker's, once its job ends
        busy.result(timeout=60)
        assert first.result(timeout=60) == [] and second.result(timeout=60) == []
        assert given_back[0].value == 2 and given_back[1].is_set()
        assert not any(pool.submit(context_made).result() for _ in range(4))


def test_a_context_given_back_is_made_again_and_draws_the_same(tmp_path):
    """`gl_context.release_context` in a fresh process: the context is gone (and a second call
    has none to give back); the next renderer makes a new one and draws the same pixels."""
    from drivee2e_data.sim.gl_context import gl_available

    if not gl_available():
        pytest.skip("no OpenGL context can be made here")
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        first, released, cached, again, second = pool.apply(_draw_release_draw)
    assert released and cached == 0 and not again
    assert first.shape == (24, 32, 3) and np.array_equal(first, second)
    assert first[12, 16, 0] > 100  # the red cube is there


def _draw_release_draw():
    import pybullet

    from drivee2e_data.sim import gl_context, gl_renderer
    from drivee2e_data.sim.conditions import ShaderLook

    look = ShaderLook(
        light_direction=(0.0, 0.0, 1.0), sun_rgb=(0.5, 0.5, 0.5), sky_ambient=(0.5, 0.5, 0.5),
        ground_ambient=(0.5, 0.5, 0.5), zenith_rgb=(0.7, 0.8, 0.9), horizon_rgb=(0.7, 0.8, 0.9),
        cloud_cover=0.0, cloud_rgb=(1.0, 1.0, 1.0), sun_disc=0.0, shadows=True,
        fog_rgb=(0.8, 0.8, 0.8), fog_density=0.0, wetness=0.0, lamps_on=False, headlights=False,
    )  # fmt: skip
    client = pybullet.connect(pybullet.DIRECT)
    shape = pybullet.createVisualShape(
        pybullet.GEOM_BOX, halfExtents=[1, 1, 1], rgbaColor=[1, 0, 0, 1], physicsClientId=client
    )
    pybullet.createMultiBody(0, -1, shape, [10, 0, 1], physicsClientId=client)
    view = pybullet.computeViewMatrix([0, 0, 1], [1, 0, 1], [0, 0, 1], physicsClientId=client)
    projection = pybullet.computeProjectionMatrixFOV(40.0, 32 / 24, 0.5, 200.0,
                                                     physicsClientId=client)  # fmt: skip

    def draw():
        renderer = gl_renderer.GLRenderer(pybullet, client, [], look)
        renderer.sync(1)
        rgb = np.array(renderer.draw(view, projection, 32, 24, False, 200.0)[0])
        renderer.release()
        return rgb

    first = draw()
    released = gl_context.release_context()
    cached = gl_context.context.cache_info().currsize
    again = gl_context.release_context()
    second = draw()
    pybullet.disconnect(client)
    return first, released, cached, again, second


def test_segments_drawn_by_different_gl_drivers_still_make_one_log() -> None:
    """A cluster's nodes may draw with different GPUs: the driver is not part of what the
    segments of one log must share; the renderer, look and rig are."""
    header = {"collection": {"renderer": "gl", "look": "6", "gl_driver": "NVIDIA H100, OpenGL 4.6"},
              "labels": None}  # fmt: skip
    other = {**header, "collection": {**header["collection"], "gl_driver": "NVIDIA A100"}}
    assert segments._records(header) == segments._records(other)
    tiny = {**header, "collection": {**header["collection"], "renderer": "tiny"}}
    assert segments._records(header) != segments._records(tiny)
