"""The feature cache: a cached sample equals the Dataset's (images to the byte, trajectories
exactly), a re-collected log or another spec makes a new folder and a stale one is never read,
a killed build resumes, and a training from the cache is the training from the Dataset."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from drivee2e_data.agents import admlp, camera
from drivee2e_data.agents.training import TrainOptions
from drivee2e_data.cli import main
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.loaders import cache
from drivee2e_data.loaders.cache import FeatureCache, FeatureSpec

SPEC = FeatureSpec("test", cameras=camera.FRONT_CAMERAS, image_size=(64, 36))


@pytest.fixture()
def root(loader_root: Path, tmp_path: Path) -> Path:
    """The loader set (4 collected clips, 2 in train), its own copy: the tests touch logs."""
    copy = tmp_path / "data"
    shutil.copytree(loader_root, copy, ignore=shutil.ignore_patterns("features"))
    return copy


def test_a_cached_sample_is_the_datasets_sample(root: Path) -> None:
    report = cache.build(root, SPEC, "all", workers=2)
    assert len(report.written) == 4 and report.samples > 0
    cached = FeatureCache(root, SPEC, "all")
    dataset = SPEC.dataset(root, "all")
    assert cached.samples == dataset.samples
    for index in range(len(dataset)):
        expected, got = dataset[index], cached[index]
        for name in SPEC.all_fields():
            assert got[name].dtype == expected[name].dtype, name
            assert torch.equal(got[name], expected[name]), (index, name)
        assert got["category"] == expected["category"]
    batch = cached.rows([3, 0, 3])
    assert torch.equal(batch["img"][1], dataset[0]["img"])
    assert torch.equal(batch["gt_ego_fut_trajs"][0], dataset[3]["gt_ego_fut_trajs"])


def test_a_recollected_log_is_cached_again_never_read_stale(root: Path) -> None:
    cache.build(root, SPEC, "train")
    log = root / "logs" / f"{FeatureCache(root, SPEC, 'train').samples[0][0]}.mcap"
    scenario_id = log.stem
    before = sorted(p.name for p in cache.spec_folder(root, SPEC).glob(f"{scenario_id}-*"))
    status = log.stat()
    os.utime(log, ns=(status.st_atime_ns, status.st_mtime_ns + 1_000_000_000))
    with pytest.raises(DriveE2EError, match="not cached for its current log"):
        FeatureCache(root, SPEC, "train")
    report = cache.build(root, SPEC, "train")
    assert report.written == [scenario_id] and len(report.reused) == 1
    after = sorted(p.name for p in cache.spec_folder(root, SPEC).glob(f"{scenario_id}-*"))
    assert len(before) == len(after) == 1 and before != after  # the stale folder is gone
    assert len(FeatureCache(root, SPEC, "train")) > 0


def test_another_spec_is_another_folder() -> None:
    other = FeatureSpec("test", cameras=camera.FRONT_CAMERAS, image_size=(32, 18))
    assert SPEC.key() != other.key() and SPEC.key().startswith("test-")
    assert (
        SPEC.key() == FeatureSpec("test", cameras=camera.FRONT_CAMERAS, image_size=(64, 36)).key()
    )


def test_a_killed_build_resumes_from_the_clips_it_finished(root: Path) -> None:
    cache.build(root, SPEC, "train")
    folder = cache.spec_folder(root, SPEC)
    done = sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))
    # a build killed while writing the second clip: its folder under a temporary name, of a
    # process that is gone
    abandoned = folder / f".{done[1].name}.999999999.tmp"
    done[1].rename(abandoned)
    report = cache.build(root, SPEC, "train")
    assert report.written == [done[1].name.rsplit("-", 1)[0]]
    assert report.reused == [done[0].name.rsplit("-", 1)[0]]
    assert not abandoned.exists()


def test_training_from_the_cache_is_training_from_the_dataset(root: Path, tmp_path: Path) -> None:
    options = TrainOptions(epochs=2, batch_size=4, seed=3)
    from_logs = camera.train(camera.dataset_for(root, "train"), tmp_path / "a.pt", options)
    cached = cache.cached(root, camera.FEATURES, "train", workers=2)
    from_cache = camera.train(cached, tmp_path / "b.pt", options)
    assert from_logs["losses"] == from_cache["losses"]
    for name, weights in from_logs["model"].items():
        assert torch.equal(weights, from_cache["model"][name]), name
    ego = cache.cached(root, admlp.FEATURES, "train")
    first = admlp.train(admlp.FEATURES.dataset(root, "train"), tmp_path / "c.pt", options)
    second = admlp.train(ego, tmp_path / "d.pt", options)
    assert first["losses"] == second["losses"]


def test_train_and_predict_build_the_cache_and_say_what_is_missing(
    root: Path, tmp_path: Path, capsys
) -> None:
    with pytest.raises(DriveE2EError, match="drivee2e cache"):
        FeatureCache(root, admlp.FEATURES, "val")
    out = tmp_path / "admlp.pt"
    assert main(["train", "admlp", str(root), "--out", str(out), "--epochs", "2"]) == 0
    assert "cached ego features of 2 clips" in capsys.readouterr().out
    predictions = tmp_path / "plans.parquet"
    args = ["predict", str(root), "--model", "admlp", "--checkpoint", str(out)]
    assert main([*args, "--out", str(predictions)]) == 0
    reference = tmp_path / "reference.parquet"
    assert main([*args, "--out", str(reference), "--no-cache"]) == 0
    import pyarrow.parquet as pq

    assert pq.read_table(predictions).equals(pq.read_table(reference))
    scored = {}
    for name, extra in (("cache", []), ("logs", ["--no-cache"])):
        scored[name] = tmp_path / f"{name}.json"
        assert main(["openloop", str(root), "--predictions", str(predictions), "--convention",
                     "uniad", "--json", str(scored[name]), *extra]) == 0  # fmt: skip
    assert scored["cache"].read_text() == scored["logs"].read_text()
    assert '"collision_3s"' in scored["cache"].read_text()
    assert main(["cache", str(root), "--model", "tcp", "--split", "val", "--workers", "1"]) == 0
    assert "1 clips written, 0 already cached" in capsys.readouterr().out
    np.testing.assert_equal(
        len(FeatureCache(root, admlp.FEATURES, "val")), len(admlp.FEATURES.dataset(root, "val"))
    )
