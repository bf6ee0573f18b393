"""Benchmark v1's helpers: nested, behaviour-stratified subsets of the committed 800-clip
manifest with one val subset, and Kendall's tau on known rankings."""

from __future__ import annotations

import csv
import importlib.util
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

REPOSITORY = Path(__file__).resolve().parent.parent
MANIFEST = REPOSITORY / "splits" / "synthetic-800.csv"


def _script(name: str):  # type: ignore[no-untyped-def]
    """A script's module: the user's scripts/ first, then the developers' scripts/dev/."""
    path = REPOSITORY / "scripts" / f"{name}.py"
    if not path.is_file():
        path = REPOSITORY / "scripts" / "dev" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as stream:
        return list(csv.DictReader(stream))


def test_subsets_are_nested_stratified_and_share_their_val_clips(tmp_path: Path) -> None:
    out = tmp_path / "manifests"
    command = [sys.executable, str(REPOSITORY / "scripts" / "benchmark_subsets.py"),
               str(MANIFEST), "--sizes", "25", "100", "400", "--val", "40", "--out", str(out)]  # fmt: skip
    subprocess.run(command, check=True, capture_output=True)
    manifest = _rows(MANIFEST)
    shares = Counter(r["category"] for r in manifest if r["split"] == "train")
    subsets = {n: _rows(out / f"train-{n}.csv") for n in (25, 100, 400)}
    train = {n: {r["scenario_id"] for r in rows if r["split"] == "train"} for n, rows in
             subsets.items()}  # fmt: skip
    val = {n: {r["scenario_id"] for r in rows if r["split"] == "val"} for n, rows in
           subsets.items()}  # fmt: skip
    assert [len(train[n]) for n in (25, 100, 400)] == [25, 100, 400]
    assert train[25] <= train[100] <= train[400]
    assert val[25] == val[100] == val[400] and len(val[25]) == 40
    by_id = {r["scenario_id"]: r for r in manifest}
    for n in (25, 100):
        counts = Counter(by_id[i]["category"] for i in train[n])
        for category, total in shares.items():  # each category within a clip of its share
            assert abs(counts[category] - n * total / 400) <= 1.0, (n, category)
    # the rows are the manifest's own, and clips.txt names every clip any subset needs
    assert all(by_id[r["scenario_id"]] == {**r} for r in subsets[100])
    needed = set((out / "clips.txt").read_text().split())
    assert needed == train[400] | val[25]
    again = tmp_path / "again"
    subprocess.run([*command[:-1], str(again)], check=True, capture_output=True)
    assert (again / "train-100.csv").read_bytes() == (out / "train-100.csv").read_bytes()


def test_kendall_tau_on_known_rankings() -> None:
    tau = _script("benchmark_report").kendall_tau
    assert tau([1, 2, 3, 4], [10, 20, 30, 40]) == pytest.approx(1.0)
    assert tau([1, 2, 3, 4], [40, 30, 20, 10]) == pytest.approx(-1.0)
    # one swapped pair of six: (5 - 1) / 6
    assert tau([1, 2, 3, 4], [10, 20, 40, 30]) == pytest.approx(4 / 6)
    # a tie in the first: tau-b, (5 - 0) / sqrt(5 * 6)
    assert tau([1, 1, 3, 4], [10, 20, 30, 40]) == pytest.approx(5 / 30**0.5)


def test_gpu_load_is_each_gpus_mean_over_nvidia_smis_samples(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.syspath_prepend(str(REPOSITORY / "scripts" / "dev"))
    gpus = _script("bench_gpus")
    samples = tmp_path / "samples.csv"
    samples.write_text("0, 80 %\n1, 60 %\n0, 90 %\n1, 70 %\n0, [N/A]\n")
    assert gpus._gpu_load(samples) == "0: 85%, 1: 65%"
    samples.write_text("")
    assert gpus._gpu_load(samples) == "not sampled"
    # a set to copy must be a data root: one clear error naming it
    with pytest.raises(SystemExit, match="nowhere: no scenarios/ folder"):
        gpus.copy_scenarios(tmp_path / "nowhere", tmp_path / "copy")


def test_a_box_edge_behind_the_camera_is_cut_at_the_near_plane() -> None:
    # plot_log_frame draws a box beside the ego in the side cameras: the part of each edge in
    # front of the camera
    visible_edge = _script("plot_log_frame").visible_edge
    ahead, behind = np.array([1.0, 2.0, 4.5]), np.array([1.0, 2.0, -3.5])
    first, second = visible_edge(ahead, behind)
    assert first.tolist() == ahead.tolist() and second.tolist() == [1.0, 2.0, 0.5]
    first, second = visible_edge(behind, ahead)  # either way round
    assert first.tolist() == [1.0, 2.0, 0.5] and second.tolist() == ahead.tolist()
    assert visible_edge(behind, np.array([0.0, 0.0, 0.2])) is None
    whole = visible_edge(ahead, np.array([3.0, 0.0, 9.0]))
    assert [p.tolist() for p in whole] == [ahead.tolist(), [3.0, 0.0, 9.0]]


def test_the_end_of_a_run_is_split_into_its_logs_and_its_workers_exits() -> None:
    profile = _script("profile_run_end")
    stamps = profile.Stamps(started=100.0, returned=131.0, last_frame=129.0)
    stamps.log("a", 127.0, 128.5)  # made final before the last frame: not part of the end
    stamps.log("b", 129.2, 130.4)
    stamps.shutdowns += [(False, 129.5, 129.5), (True, 130.6, 130.9)]
    parts = profile.end_parts(stamps)
    assert parts == pytest.approx({"logs": 1.4, "exits": 1.4, "end": 2.0})
    quiet = profile.Stamps(started=0.0, returned=5.0, last_frame=4.5)
    assert profile.end_parts(quiet) == pytest.approx({"logs": 0.0, "exits": 0.0, "end": 0.5})


@pytest.mark.slow
def test_processes_exit_measured_with_and_without_a_gl_context() -> None:
    # its own process: the processes are forked, and a parent holding a GL context (as this
    # one may, from other tests) would hand them one that cannot work
    result = subprocess.run(
        [sys.executable, str(REPOSITORY / "scripts" / "dev" / "bench_context_exit.py"), "--processes", "2"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    if "no GL context" in result.stderr:
        pytest.skip("no OpenGL context can be made here")
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].startswith("2 processes")
    exits = [line.split() for line in lines[1:] if "exited" in line]
    seconds = {words[0]: float(words[3]) for words in exits}
    assert set(seconds) == {"held", "released", "early", "none"}
    assert all(0.0 < value < 30.0 for value in seconds.values())
    made = [line.split() for line in lines[1:] if "made a context" in line]
    assert [words[0] for words in made] == ["held", "released", "early"]  # none makes none
    (given,) = [line.split() for line in lines[1:] if "gave its context back" in line]
    assert given[0] == "early" and 0.0 < float(given[6]) <= float(given[12]) < 30.0
    for words in made:
        median, longest = float(words[5]), float(words[8])
        ready, span = float(words[11]), float(words[15])
        assert 0.0 < median <= longest <= span < 30.0 and ready <= span


def test_context_creation_is_summarised_by_median_longest_and_span() -> None:
    bench = _script("bench_context_exit")
    made = bench.creation([(10.0, 10.5), (10.1, 11.1), (10.2, 10.4)])
    assert made == pytest.approx({"median": 0.5, "longest": 1.0, "ready": 0.5, "span": 1.1})
    assert bench.creation([(0.0, 2.0), (1.0, 2.0)])["median"] == pytest.approx(1.5)


def test_host_cpu_bench_reports_each_count_against_one_process() -> None:
    result = subprocess.run(
        [sys.executable, str(REPOSITORY / "scripts" / "dev" / "bench_host_cpu.py"),
         "--processes", "2", "--seconds", "0.3", "--images", "2"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    rows = [line.split() for line in result.stdout.splitlines()[1:]]
    assert [int(words[0]) for words in rows] == [1, 2]  # one process added as the reference
    assert rows[0][-3] == "1.00x"
    each, total = float(rows[1][2]), float(rows[1][4])
    assert each > 0 and total == pytest.approx(2 * each, rel=0.01)


def test_host_cpu_bench_image_is_camera_sized_and_the_same_each_time() -> None:
    bench = _script("bench_host_cpu")
    image = bench.camera_like_image()
    assert image.shape == (900, 1600, 3) and image.dtype == np.uint8
    assert np.array_equal(image, bench.camera_like_image())
    assert not np.array_equal(image, bench.camera_like_image(seed=1))


def test_host_load_reads_the_cpus_shares_from_proc_stat(monkeypatch) -> None:
    monkeypatch.syspath_prepend(str(REPOSITORY / "scripts" / "dev"))
    load = _script("host_load")
    before = load.cpu_times("cpu  100 0 50 800 50 0 0 0 0 0\ncpu0 1 2 3 4\nintr 5\n")
    after = load.cpu_times("cpu  400 100 100 1300 50 25 25 0 0 0\n")
    # 1000 jiffies between: 400 user and nice, 100 system and interrupts, 500 idle, 0 steal
    shares = load.shares(before, after)
    assert (shares.user, shares.system, shares.idle, shares.steal) == (0.4, 0.1, 0.5, 0.0)
    assert load.shares(after, after) == load.CpuShares(0.0, 0.0, 0.0, 0.0)
    start = load.CpuShares(0.1, 0.05, 0.85, 0.0)
    middle = load.CpuShares(0.95, 0.03, 0.02, 0.0)
    end = load.CpuShares(0.3, 0.1, 0.6, 0.0)
    assert load.busy_middle([start, middle, end, middle]) == [middle, middle]
    with pytest.raises(ValueError, match="no 'cpu' line"):
        load.cpu_times("intr 5\n")


def test_host_load_runs_the_command_and_exits_with_its_status() -> None:
    command = [sys.executable, str(REPOSITORY / "scripts" / "dev" / "host_load.py"), "--interval", "0.2",
               "--", sys.executable, "-c", "import sys, time; time.sleep(0.5); sys.exit(3)"]  # fmt: skip
    result = subprocess.run(
        command, capture_output=True, text=True, cwd=REPOSITORY / "scripts" / "dev"
    )
    assert result.returncode == 3, result.stderr
    assert "exit 3" in result.stdout and "CPUs, busy middle: user" in result.stdout


def test_spy_stages_counts_samples_by_stage_and_the_drivers_share(
    tmp_path: Path, monkeypatch
) -> None:
    monkeypatch.syspath_prepend(str(REPOSITORY / "scripts" / "dev"))
    spy = _script("spy_stages")
    capture = "capture_frames (collect/job.py:211);SensorSuite.capture (sensors/suite.py:202)"
    read = f"{capture};render (sensors/camera.py:99);Framebuffer.read_into (moderngl/m.py:409)"
    lidar = f"{capture};depth_sweep (sensors/lidar_depth.py:199)"
    feeder = "Thread.run (threading.py:1012);Queue._feed (multiprocessing/queues.py:231)"
    raw = tmp_path / "worker.txt"
    raw.write_text(
        f"{read};0x7f64 (libnvidia-eglcore.so.580) 6\n"
        f"{read};0x7f65 ([vdso]) 2\n"
        f"{capture};encode_jpeg (sensors/camera.py:150);0x7f66 (cv2/cv2.abi3.so) 4\n"
        f"{lidar};_sample (sensors/lidar_depth.py:240) 8\n"
        f"{feeder};Condition.wait (threading.py:327) 30\n"
    )
    samples = spy.read_samples([raw])
    total, stages = spy.shares(samples)
    # the feeder thread's 30 left out; cameras 8 of 20, all of them in the driver or its clock
    assert total == 20
    assert stages == {"cameras drawn and read": (8, 8), "lidar": (8, 0), "jpeg": (4, 0)}
    functions = spy.innermost_python(samples)
    assert functions["Framebuffer.read_into (m.py)"] == 8
    assert functions["_sample (lidar_depth.py)"] == 8
    assert functions["encode_jpeg (camera.py)"] == 4
    raw.write_text("no count here\n")
    with pytest.raises(SystemExit, match=r"worker\.txt line 1: expected"):
        spy.read_samples([raw])


def test_closed_loop_timeline_puts_each_episode_on_the_first_row_free_at_its_start() -> None:
    lanes = _script("closedloop_breakdown").lanes
    rows = [
        {"started_at": 0.0, "ended_at": 5.0},
        {"started_at": 0.1, "ended_at": 3.0},
        {"started_at": 3.0, "ended_at": 9.0},  # the second row is free again at 3
        {"started_at": 4.0, "ended_at": 6.0},  # both busy: a third row
        {"started_at": 6.5, "ended_at": 8.0},  # the first row (free since 5) before the third
    ]
    assert lanes(rows) == [0, 1, 1, 2, 0]
