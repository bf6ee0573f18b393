"""Shared fixtures: one synthetic data root per test session, made through the CLI. Under
pytest-xdist (`scripts/test.sh` runs a worker per core) each root is made once, by the first
worker to need it, and every worker reads its own copy of it."""

from __future__ import annotations

import dataclasses
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
from filelock import FileLock

from drivee2e_data import splits, store
from drivee2e_data.cli import main
from drivee2e_data.processes import usable_cores

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
DEFAULT_CLIPS = 12
# a test file's weight for dealing files to pytest-xdist's workers: seconds a test takes on
# the 2-core machine, the median of those marked slow and of the others (2026-11-29)
SLOW_TEST_S, TEST_S = 8.0, 0.3


# native thread pools a test process may start (torch's intra-op pool, OpenBLAS, MKL)
NATIVE_THREADS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def pytest_configure(config: pytest.Config) -> None:
    """Under pytest-xdist, each worker's native thread pools sized to its share of the cores
    (set in the controller before it starts the workers, which inherit them, as do the
    processes their tests start; a setting of the user's own is kept). With a worker per core,
    torch's and OpenBLAS's default of a thread per core only fought the other worker: the
    training tests' threads spin while they wait (2 cores: pytest 5 min 28 s -> 4 min 27 s,
    docs/benchmarks.md)."""
    workers = getattr(config.option, "numprocesses", None)
    if not workers or "PYTEST_XDIST_WORKER" in os.environ:
        return
    cores = usable_cores()
    workers = cores if workers == "auto" else int(workers)
    for name in NATIVE_THREADS:
        os.environ.setdefault(name, str(max(1, cores // max(1, workers))))


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Under pytest-xdist, the test files heaviest first (each file's tests in their order):
    `scripts/test.sh` deals whole files to the workers in this order (`--dist loadfile
    --no-loadscope-reorder`), so the run's last minutes hold only short files and no worker
    waits long for the other at the end (longest first; xdist's own order, by the number of
    tests, left a file of three long tests to run alone for its last 20 s)."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        return
    weights: dict[str, float] = {}
    for item in items:
        file = item.nodeid.split("::")[0]
        weights[file] = weights.get(file, 0.0) + (
            SLOW_TEST_S if item.get_closest_marker("slow") else TEST_S
        )
    items.sort(key=lambda item: -weights[item.nodeid.split("::")[0]])  # stable: files stay whole


def made_once(
    tmp_path_factory: pytest.TempPathFactory, name: str, make: Callable[[Path], None]
) -> Path:
    """A data root `make(root)` fills, made once per test run: by this process alone, or under
    pytest-xdist by the first worker to ask (the others wait on a lock) in the run's shared
    temporary folder, then copied into this worker's own (its tests may write beside the data,
    as they do in a run without workers)."""
    root = tmp_path_factory.mktemp(name) / "data"
    if "PYTEST_XDIST_WORKER" not in os.environ:
        make(root)
        return root
    shared = tmp_path_factory.getbasetemp().parent / f"made_once_{name}"
    with FileLock(f"{shared}.lock"):
        if not (shared / "made").exists():
            shutil.rmtree(shared, ignore_errors=True)
            make(shared / "data")
            (shared / "made").touch()
    shutil.copytree(shared / "data", root, symlinks=True)
    return root


@pytest.fixture(scope="session")
def synthetic_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The default set: `drivee2e synth --clips 12 --seed 0` (with a process per core: the same
    files as one process makes)."""

    def make(root: Path) -> None:
        arguments = ["synth", "--out", str(root), "--clips", str(DEFAULT_CLIPS), "--seed", "0"]
        assert main([*arguments, "--workers", str(min(4, os.cpu_count() or 1))]) == 0

    return made_once(tmp_path_factory, "synth", make)


@pytest.fixture(scope="session")
def synthetic_scenarios(synthetic_root: Path) -> list:
    return [store.read_scenario(synthetic_root, i) for i in store.scenario_ids(synthetic_root)]


def copy_clips(source: Path, destination: Path, scenario_ids: list[str]) -> Path:
    """A new data root holding these clips of `source` and their maps."""
    for scenario_id in scenario_ids:
        shutil.copytree(
            store.scenario_dir(source, scenario_id), store.scenario_dir(destination, scenario_id)
        )
        map_id = store.read_scenario(source, scenario_id).map_id
        target = store.map_path(destination, map_id)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(store.map_path(source, map_id), target)
    return destination


# collection in tests: small images, a few frames, the full LiDAR and radars
SMALL_COLLECT = ["--image-size", "160x90", "--jpeg-quality", "80"]
LONG_CLIP_FRAMES = 36  # enough for the 3 s future of frame 0 and a little more


@pytest.fixture(scope="session")
def collected_root(synthetic_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two clips of the default set collected: the first for 36 frames, the second for 6."""
    ids = store.scenario_ids(synthetic_root)[:2]

    def make(root: Path) -> None:
        copy_clips(synthetic_root, root, ids)
        for scenario_id, frames in ((ids[0], LONG_CLIP_FRAMES), (ids[1], 6)):
            arguments = ["--only", scenario_id, "--max-frames", str(frames), *SMALL_COLLECT]
            assert main(["collect", str(root), *arguments]) == 0

    return made_once(tmp_path_factory, "collected", make)


@pytest.fixture(scope="session")
def loader_root(
    synthetic_root: Path, collected_root: Path, tmp_path_factory: pytest.TempPathFactory
) -> Path:
    """Four collected clips (one per behaviour: STR 36 frames, LFT 6, RT 8, STP 8) in a 2:1:1
    manifest `splits/default.csv`: train LFT + RT, val STP, test STR (the straight clip)."""
    ids = store.scenario_ids(synthetic_root)[:4]

    def make(root: Path) -> None:
        copy_clips(synthetic_root, root, ids)
        logs = collected_root / "logs"
        shutil.copytree(logs, root / "logs", ignore=shutil.ignore_patterns(".*"))
        for scenario_id in ids[2:]:
            arguments = ["--only", scenario_id, "--max-frames", "8", *SMALL_COLLECT]
            assert main(["collect", str(root), *arguments]) == 0
        assigned = dict(zip(ids, ("test", "train", "train", "val"), strict=True))
        rows = [
            dataclasses.replace(row, split=assigned[row.scenario_id])
            for row in splits.clips_of(root)
        ]
        splits.write_manifest(splits.split_path(root, "default"), rows)

    return made_once(tmp_path_factory, "loader", make)
