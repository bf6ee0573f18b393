"""Shared fixtures: one synthetic data root per test session, made through the CLI."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import pytest

from drivee2e_data import splits, store
from drivee2e_data.cli import main

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
DEFAULT_CLIPS = 12


@pytest.fixture(scope="session")
def synthetic_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The default set: `drivee2e synth --clips 12 --seed 0`."""
    root = tmp_path_factory.mktemp("synth") / "data"
    assert main(["synth", "--out", str(root), "--clips", str(DEFAULT_CLIPS), "--seed", "0"]) == 0
    return root


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
    root = copy_clips(synthetic_root, tmp_path_factory.mktemp("collected") / "data", ids)
    for scenario_id, frames in ((ids[0], LONG_CLIP_FRAMES), (ids[1], 6)):
        code = main(
            [
                "collect",
                str(root),
                "--only",
                scenario_id,
                "--max-frames",
                str(frames),
                *SMALL_COLLECT,
            ]
        )
        assert code == 0
    return root


@pytest.fixture(scope="session")
def loader_root(
    synthetic_root: Path, collected_root: Path, tmp_path_factory: pytest.TempPathFactory
) -> Path:
    """Four collected clips (one per behaviour: STR 36 frames, LFT 6, RT 8, STP 8) in a 2:1:1
    manifest `splits/default.csv`: train LFT + RT, val STP, test STR (the straight clip)."""
    ids = store.scenario_ids(synthetic_root)[:4]
    root = copy_clips(synthetic_root, tmp_path_factory.mktemp("loader") / "data", ids)
    shutil.copytree(collected_root / "logs", root / "logs", ignore=shutil.ignore_patterns(".*"))
    for scenario_id in ids[2:]:
        code = main(
            ["collect", str(root), "--only", scenario_id, "--max-frames", "8", *SMALL_COLLECT]
        )
        assert code == 0
    assigned = dict(zip(ids, ("test", "train", "train", "val"), strict=True))
    rows = [
        dataclasses.replace(row, split=assigned[row.scenario_id]) for row in splits.clips_of(root)
    ]
    splits.write_manifest(splits.split_path(root, "default"), rows)
    return root
