"""The collector: crash safety and resume, determinism, failures reported, the frame index, and
annotations that agree with the cameras' segmentation."""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import SMALL_COLLECT, copy_clips
from mcap.reader import make_reader

from drivee2e_data import store
from drivee2e_data.cli import main
from drivee2e_data.logs.reader import LogReader, validate
from drivee2e_data.sensors import annotate
from drivee2e_data.sensors.camera import render
from drivee2e_data.sensors.suite import SensorSuite, SuiteOptions
from drivee2e_data.sim.world import World


def _payloads(path: Path) -> dict[tuple[str, int], bytes]:
    with open(path, "rb") as stream:
        return {
            (channel.topic, message.log_time): message.data
            for _, channel, message in make_reader(stream).iter_messages()
        }


def _start_collector(
    root: Path, arguments: list[str], temporary: Path | None = None
) -> subprocess.Popen:
    """`drivee2e collect` in a process group of its own, as a terminal would start it: with
    Ctrl-C's default action even where the tests run in the background (a shell without job
    control starts background commands with SIGINT ignored, and Python keeps it ignored);
    `temporary`: its temp folder (TMPDIR)."""
    command = [sys.executable, "-m", "drivee2e_data.cli", "collect", str(root), *arguments]
    environment = None if temporary is None else {**os.environ, "TMPDIR": str(temporary)}
    return subprocess.Popen(
        [*command, *SMALL_COLLECT],
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=environment,
    )


def _wait_until(condition, process: subprocess.Popen, seconds: float = 240) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + seconds
    while not condition():
        assert process.poll() is None, "the collector ended before the test could stop it"
        assert time.monotonic() < deadline, "the collector never got there"
        time.sleep(0.05)


@pytest.mark.slow
def test_sigkill_mid_clip_then_rerun_completes_every_log(synthetic_root: Path, tmp_path: Path):
    ids = store.scenario_ids(synthetic_root)[2:5]
    root = copy_clips(synthetic_root, tmp_path / "data", ids)
    process = _start_collector(root, ["--max-frames", "8", "--workers", "1"])
    logs = root / "logs"

    first_seen: dict[str, int] = {}

    def second_clip_capturing() -> bool:
        """The second clip's partial log has grown since the test first saw it: its frames are
        going in (a fixed wait after its header let a faster collector finish the clip)."""
        partial = list(logs.glob(".*.partial"))
        if len(list(logs.glob("*.mcap"))) != 1 or not partial:
            return False
        size = partial[0].stat().st_size
        return size > first_seen.setdefault(partial[0].name, size)

    try:
        _wait_until(second_clip_capturing, process)
        os.killpg(process.pid, signal.SIGKILL)
    finally:
        process.wait()
    finished = sorted(logs.glob("*.mcap"))
    assert len(finished) == 1 and list(logs.glob(".*.partial"))  # the kill left a partial
    first = finished[0]
    before = (first.read_bytes(), first.stat().st_mtime_ns)

    assert main(["collect", str(root), "--max-frames", "8", *SMALL_COLLECT]) == 0
    logs_now = sorted(p.name for p in logs.iterdir() if not p.name.startswith(".collect"))
    assert logs_now == sorted([f"{s}.mcap" for s in ids] + ["index.parquet"])  # no partials
    assert (first.read_bytes(), first.stat().st_mtime_ns) == before
    for scenario_id in ids:
        assert validate(logs / f"{scenario_id}.mcap") == 8
    index = pq.read_table(logs / "index.parquet").to_pydict()
    assert len(index["frame"]) == 24 and sorted(set(index["scenario_id"])) == ids


def test_same_clip_twice_gives_identical_payloads(
    collected_root: Path, synthetic_root: Path, tmp_path: Path
):
    scenario_id = store.scenario_ids(synthetic_root)[1]
    again = copy_clips(synthetic_root, tmp_path / "again", [scenario_id])
    assert main(["collect", str(again), "--max-frames", "6", *SMALL_COLLECT]) == 0
    first = _payloads(collected_root / "logs" / f"{scenario_id}.mcap")
    second = _payloads(again / "logs" / f"{scenario_id}.mcap")
    assert first.keys() == second.keys()
    different = [key for key in first if first[key] != second[key]]
    assert different == []


def test_rerun_skips_finished_logs(collected_root: Path, capsys):
    logs = sorted((collected_root / "logs").glob("*.mcap"))
    stamps = [(p.stat().st_mtime_ns, p.stat().st_size) for p in logs]
    assert main(["collect", str(collected_root), *SMALL_COLLECT]) == 0
    assert "0 clips collected, 2 already done, 0 failed" in capsys.readouterr().out
    assert [(p.stat().st_mtime_ns, p.stat().st_size) for p in logs] == stamps


def test_a_failing_clip_is_reported_and_the_others_finish(
    synthetic_root: Path, tmp_path: Path, capsys
):
    good = store.scenario_ids(synthetic_root)[5]
    root = copy_clips(synthetic_root, tmp_path / "data", [good])
    scenario = store.read_scenario(root, good)
    # an ego that leaves the clip half way: collection needs the ego at every frame
    leaving = next(
        t for t in scenario.tracks if t.agent_class.is_motor_vehicle and not t.valid.all()
    )
    broken = dataclasses.replace(scenario, scenario_id="broken_ego", ego_id=leaving.track_id)
    store.write_scenario(root, broken)
    assert main(["collect", str(root), "--max-frames", "3", *SMALL_COLLECT]) == 1
    captured = capsys.readouterr()
    assert "1 clips collected, 0 already done, 1 failed" in captured.out
    assert "failed: broken_ego:" in captured.err and leaving.track_id in captured.err
    assert sorted(p.name for p in (root / "logs").glob("*.mcap")) == [f"{good}.mcap"]
    assert not list((root / "logs").glob(".*.partial"))


@pytest.mark.parametrize(
    ("arguments", "expected"),
    [
        (["--image-size", "12x5"], "at least 16x16"),
        (["--image-size", "wide"], "expected WxH"),
        (["--only", "no_such_clip"], "no scenario 'no_such_clip'"),
    ],
)
def test_bad_collect_arguments_are_clear_errors(
    collected_root: Path, arguments: list[str], expected: str, capsys
):
    try:
        code = main(["collect", str(collected_root), *arguments])
    except SystemExit as exit_:
        code = exit_.code
    assert code == 2
    assert expected in capsys.readouterr().err


def test_gpu_post_processing_without_cuda_is_a_clear_error(collected_root: Path, capsys):
    from drivee2e_data.sensors.camera_gpu import cuda_available

    if cuda_available():
        pytest.skip("this machine has CUDA")
    assert main(["collect", str(collected_root), "--post-process", "cuda"]) == 2
    assert "post-process device 'cuda': torch sees no CUDA device here" in capsys.readouterr().err


def test_index_rows_follow_the_scenario(collected_root: Path):
    table = pq.read_table(collected_root / "logs" / "index.parquet").to_pylist()
    assert len(table) == 36 + 6
    first = next(row for row in table if row["frame"] == 0)
    scenario = store.read_scenario(collected_root, first["scenario_id"])
    assert first["t_ns"] == scenario.t_ns[0]
    assert first["sub_scenario"] == scenario.behavior.sub_scenario.value
    assert first["speed_mps"] == pytest.approx(scenario.ego.speed_mps[0])


def test_boxes_seen_by_a_camera_are_in_its_image_and_mask(synthetic_root: Path):
    scenario_id = store.scenario_ids(synthetic_root)[0]
    scenario = store.read_scenario(synthetic_root, scenario_id)
    with World(store.read_map(synthetic_root, scenario.map_id), scenario) as world:
        suite = SensorSuite(world, SuiteOptions(image_size=(320, 180)))
        frame = 30
        captured = suite.capture(frame)
        world.place_ego(
            float(scenario.ego.x_m[frame]), float(scenario.ego.y_m[frame]), scenario.ego_id
        )
        world.set_time(frame)
        views = {c.name: render(world, c, captured.ego_to_world) for c in suite.rig.cameras}
        seen = [b for b in captured.boxes if b.cameras]
        assert len(seen) >= 3
        for box in seen:
            body = world.bodies[box.track_id]
            track = scenario.track(box.track_id)
            corners = annotate.box_corners_3d(track, frame, tuple(box.size_m))
            for name in box.cameras:
                area = annotate.projected_area(views[name], corners, captured.ego_to_world)
                assert not area.is_empty and area.area > 0
                assert (views[name].mask == body).any()
            assert box.visibility == annotate.visibility_level(box.visible_share) >= 1
        unseen = [b for b in captured.boxes if not b.cameras]
        assert all(b.visibility == 0 for b in unseen)
        # LiDAR points counted in a box lie in it (the box grown by 2 cm for surface hits)
        for box in captured.boxes:
            if box.num_lidar_points == 0:
                continue
            body = world.bodies[box.track_id]
            hits = captured.lidar.points_m[captured.lidar.body == body].astype(np.float64)
            lidar_to_world = captured.ego_to_world @ suite.rig.lidar.sensor_to_ego
            world_points = hits @ lidar_to_world[:3, :3].T + lidar_to_world[:3, 3]
            grown = tuple(np.asarray(box.size_m) + 0.04)
            corners = annotate.box_corners_3d(scenario.track(box.track_id), frame, grown)
            corners[:, 2] -= 0.02
            assert annotate.points_in_box(world_points, corners) == box.num_lidar_points


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["local", "ray"])
def test_a_pool_of_workers_writes_the_same_payloads(
    backend: str, collected_root: Path, synthetic_root: Path, tmp_path: Path
):
    if backend == "ray":
        pytest.importorskip("ray", reason="the Ray backend needs the ray extra")
    ids = store.scenario_ids(synthetic_root)[:2]
    root = copy_clips(synthetic_root, tmp_path / "data", ids)
    arguments = ["collect", str(root), "--max-frames", "6", "--backend", backend, "--workers", "2"]
    assert main([*arguments, *SMALL_COLLECT]) == 0
    for scenario_id in ids:
        pooled = _payloads(root / "logs" / f"{scenario_id}.mcap")
        alone = _payloads(collected_root / "logs" / f"{scenario_id}.mcap")
        assert pooled.items() <= alone.items()  # the first clip was collected longer alone
        assert len({t for _, t in pooled}) == 6


def test_ctrl_c_stops_a_pool_at_once_and_leaves_no_partial_logs(
    synthetic_root: Path, tmp_path: Path
):
    """Three 60-frame clips on two workers: the first clip and half the second for one, the
    second's other half and the third for the other, each piece a segment (a clip's first, its
    log's head, written as a partial log). Ctrl-C while both write one leaves neither unfinished
    segment file nor any partial log, nor the workers' twin meshes in the temp folder."""
    ids = store.scenario_ids(synthetic_root)[6:9]
    root = copy_clips(synthetic_root, tmp_path / "data", ids)
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    process = _start_collector(root, ["--workers", "2", "--max-frames", "60"], temporary)
    logs = root / "logs"
    unfinished = ".segments/*/*.segment-tmp"
    partial = ".*.partial"
    _wait_until(lambda: len([*logs.glob(unfinished), *logs.glob(partial)]) == 2, process)
    os.killpg(process.pid, signal.SIGINT)  # what Ctrl-C in a terminal does
    try:
        _, err = process.communicate(timeout=30)  # not after the clips still to do
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    assert process.returncode == 130
    assert "interrupted" in err.decode() and "rerun to resume" in err.decode()
    assert not list(logs.glob(partial)) and not list(logs.glob(unfinished))
    assert len(list(logs.glob("*.mcap"))) < len(ids)
    assert not list(temporary.glob("drivee2e_twin_*"))


@pytest.mark.slow
def test_a_pool_run_that_ends_leaves_nothing_in_the_temp_folder(
    synthetic_root: Path, tmp_path: Path
):
    """Neither the workers' twin meshes and actors' shape files nor the run's shared twin plans
    stay behind: a worker forked from the pool's server never runs `atexit`."""
    ids = store.scenario_ids(synthetic_root)[:3]
    root = copy_clips(synthetic_root, tmp_path / "data", ids)
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    process = _start_collector(root, ["--workers", "2", "--max-frames", "3"], temporary)
    _, err = process.communicate(timeout=300)
    assert process.returncode == 0, err.decode()
    assert len(list((root / "logs").glob("*.mcap"))) == len(ids)
    assert not list(temporary.iterdir())


def test_a_damaged_log_is_reported_not_skipped_nor_overwritten(
    synthetic_root: Path, tmp_path: Path, capsys
):
    scenario_id = store.scenario_ids(synthetic_root)[0]
    root = copy_clips(synthetic_root, tmp_path / "data", [scenario_id])
    damaged = root / "logs" / f"{scenario_id}.mcap"
    damaged.parent.mkdir(parents=True)
    damaged.write_bytes(b"\x89MCAP0\r\n" + b"\0" * 100)  # a log cut short after its magic
    assert main(["collect", str(root), "--max-frames", "2", *SMALL_COLLECT]) == 1
    err = capsys.readouterr().err
    assert f"failed: {scenario_id}:" in err and "delete it to collect the clip again" in err
    assert damaged.read_bytes() == b"\x89MCAP0\r\n" + b"\0" * 100


def test_a_broken_bundle_fails_alone(synthetic_root: Path, tmp_path: Path, capsys):
    ids = store.scenario_ids(synthetic_root)[:2]
    root = copy_clips(synthetic_root, tmp_path / "data", ids)
    tracks = store.scenario_dir(root, ids[0]) / "tracks.parquet"
    tracks.write_bytes(tracks.read_bytes()[:100])  # truncated
    assert main(["collect", str(root), "--max-frames", "2", *SMALL_COLLECT]) == 1
    captured = capsys.readouterr()
    assert "1 clips collected, 0 already done, 1 failed" in captured.out
    assert f"failed: {ids[0]}:" in captured.err and "tracks.parquet" in captured.err
    assert [p.name for p in (root / "logs").glob("*.mcap")] == [f"{ids[1]}.mcap"]


def test_the_host_plan_fits_cores_frames_memory_and_gpus():
    from drivee2e_data.collect.host import plan

    gpu_host = plan(frames=160_000, cores=16, memory=125.0, gpu=True, renderer="gl", gpus=1)
    assert (gpu_host.workers, gpu_host.lidar) == (16, "depth")
    assert "GL renderer -> 16 workers (--workers auto), depth LiDAR" in gpu_host.describe()
    eight = plan(frames=160_000, cores=128, memory=560.0, gpu=True, renderer="gl", gpus=8)
    assert eight.workers == 128 and "8 GPUs" in eight.describe()  # the GPUs add no workers
    assert plan(frames=160_000, cores=16, memory=125.0, gpu=True, renderer="egl", gpus=8).gpus == 0
    # one 200-frame clip is cut into 25-frame segments: 8 workers, not 1
    assert plan(frames=200, cores=16, memory=125.0, gpu=False, renderer="gl").workers == 8
    assert plan(frames=75, cores=16, memory=125.0, gpu=False, renderer="gl").workers == 3
    assert (
        plan(frames=9000, cores=16, memory=6.0, gpu=False, renderer="egl").workers == 4
    )  # 1.5 GiB
    laptop = plan(frames=480, cores=2, memory=24.0, gpu=False, renderer="gl")
    assert (laptop.workers, laptop.lidar) == (2, "depth")  # llvmpipe: depth images faster
    assert "GL renderer on " in laptop.describe() and "Mesa" in laptop.mesa  # which draws
    assert gpu_host.mesa == ""  # a GPU draws: no Mesa named
    assert "-> 3 workers (--workers 3), depth LiDAR" in laptop.given(3).describe()
    assert plan(frames=480, cores=2, memory=24.0, gpu=False, renderer="egl").lidar == "depth"
    assert plan(frames=480, cores=2, memory=24.0, gpu=True, renderer="tiny").lidar == "raycast"
    assert plan(frames=0, cores=2, memory=1.0, gpu=False, renderer="tiny").workers == 1
    assert plan(frames=30, cores=2, memory=8.0, gpu=False).renderer in ("gl", "egl", "tiny")


def test_the_command_line_starts_without_torch():
    """Every `drivee2e` command imports `drivee2e_data.cli`, and so does each collection worker
    (spawned workers import the command's module again): torch, Lightning and matplotlib are
    for the commands that use them (they cost 3 s a process to import)."""
    code = (
        "import sys, drivee2e_data.cli; "
        "print(sorted({'torch', 'lightning', 'matplotlib', 'torchvision'} & set(sys.modules)))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_index_columns_are_made_from_buffers_with_the_values_given():
    """`store.arrow_column` builds the index's columns without `pa.array` (which imports pandas where
    it is installed): strings (also non-ASCII and empty) and numbers read back as given."""
    import pyarrow as pa

    from drivee2e_data.store import arrow_column

    texts = ["synth_s0_c0001", "", "Straße", "rain"]
    assert arrow_column(texts, pa.string()).to_pylist() == texts
    assert arrow_column([3, -1, 7], pa.int8()).to_pylist() == [3, -1, 7]
    assert arrow_column([1786249534000000000, 5], pa.int64()).to_pylist() == [
        1786249534000000000,
        5,
    ]
    assert arrow_column([0.25, -3.5], pa.float64()).to_pylist() == [0.25, -3.5]
    assert arrow_column([], pa.string()).to_pylist() == []


def test_a_pool_worker_reports_each_unit_as_it_ends_not_when_its_job_does(monkeypatch):
    """The parent writes a clip's log once the clip's last unit is in, and measures what a
    world costs as each is set up: a job of two units sends the first unit's set-up as it ends
    and its result before the second begins."""
    from drivee2e_data.collect import runner
    from drivee2e_data.collect.job import CollectOptions, JobResult
    from drivee2e_data.collect.segments import WorkUnit

    events: list[object] = []

    class Reports:
        def put(self, item):
            events.append(("reported", item[0], item[1].scenario_id))

    class SetUps:
        def put(self, item):
            events.append(("set up", item[0], item[1] == os.getpid(), item[2]))

    def run_unit(root, unit, options, on_frame, claim, on_setup):
        events.append(("began", unit.scenario_id))
        on_setup(0.25 if unit.scenario_id == "a" else 0.5)
        return JobResult(unit.scenario_id, "collected", frames=unit.frames)

    monkeypatch.setattr(runner, "run_unit", run_unit)
    monkeypatch.setattr(runner, "_units_done", Reports())
    monkeypatch.setattr(runner, "_setups_done", SetUps())
    monkeypatch.setattr(runner, "_frames_done", None)
    job = (WorkUnit("a", 20, 40), WorkUnit("b", 0, 30))
    results = runner._pooled_job(Path("root"), job, CollectOptions(), (3, 4))
    assert [r.scenario_id for r in results] == ["a", "b"]
    assert events == [
        ("began", "a"),
        ("set up", 3, True, 0.25),
        ("reported", 3, "a"),
        ("began", "b"),
        ("set up", 4, True, 0.5),
        ("reported", 4, "b"),
    ]


def test_a_log_names_the_gl_driver_that_drew_it(collected_root: Path):
    from drivee2e_data.sim.gl_context import gl_driver

    for path in sorted((collected_root / "logs").glob("*.mcap")):
        with LogReader(path) as log:
            collection = log.collection
        if collection["renderer"] != "gl":
            pytest.skip("the GL renderer does not draw here")
        # this process makes its context as the collector's did (the same Mesa)
        assert collection["gl_driver"] == gl_driver() and ", OpenGL " in collection["gl_driver"]


def test_ray_joins_the_cluster_ray_address_names_else_starts_its_own(monkeypatch) -> None:
    """Without RAY_ADDRESS, Ray's default joins the local cluster another process started last,
    and the run fails when that process shuts it down: the collector asks for a local one of
    its own instead."""
    ray = pytest.importorskip("ray", reason="the Ray backend needs the ray extra")
    from drivee2e_data.collect import runner

    calls: list[dict] = []
    monkeypatch.setattr(ray, "init", lambda **kwargs: calls.append(kwargs))
    monkeypatch.setattr(ray, "cluster_resources", lambda: {"CPU": 3.0})
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    assert runner._start_ray() == 3
    monkeypatch.setenv("RAY_ADDRESS", "10.0.0.5:6379")
    runner._start_ray()
    assert [call["address"] for call in calls] == ["local", "10.0.0.5:6379"]
