"""Keyframe-rate sensors (`collect --sensor-hz 2`): the ego, the lights and the IMU at every
10 Hz frame, sensors and boxes at every fifth; the log validates, the index lists the keyframes,
and the Dataset serves the same samples as a 10 Hz log's keyframes."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch
from conftest import LONG_CLIP_FRAMES, SMALL_COLLECT

from drivee2e_data.cli import main
from drivee2e_data.errors import DriveE2EError, LogFormatError
from drivee2e_data.export import common
from drivee2e_data.loaders import DriveE2EDataset
from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader, validate


@pytest.fixture(scope="module")
def keyframe_root(loader_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The loader set's test clip (straight, 36 frames) collected again at 2 Hz, with the same
    manifest."""
    root = tmp_path_factory.mktemp("keyframes") / "data"
    shutil.copytree(loader_root, root, ignore=shutil.ignore_patterns("logs"))
    test_clip = DriveE2EDataset(loader_root, "test", cameras=()).samples[0][0]
    arguments = ["collect", str(root), "--only", test_clip, "--sensor-hz", "2"]
    assert main([*arguments, "--max-frames", str(LONG_CLIP_FRAMES), *SMALL_COLLECT]) == 0
    return root


def _log(root: Path) -> Path:
    (path,) = (root / "logs").glob("*.mcap")
    return path


def test_a_keyframe_log_holds_sensors_every_fifth_frame(keyframe_root: Path) -> None:
    path = _log(keyframe_root)
    assert validate(path) == LONG_CLIP_FRAMES
    with LogReader(path) as log:
        assert log.sensor_every == 5 and log.collection["sensor_hz"] == "2"
        assert list(log.sensor_frames) == [0, 5, 10, 15, 20, 25, 30, 35]  # 36 frames: 8 keyframes
        counts = {
            channel.topic: log.summary.statistics.channel_message_counts[channel_id]
            for channel_id, channel in log.summary.channels.items()
        }
    for topic in topics.STATE_TOPICS:
        assert counts[topic] == LONG_CLIP_FRAMES
    for topic in (topics.LIDAR, topics.OBJECTS, topics.BEV, topics.image_topic("CAM_FRONT")):
        assert counts[topic] == 8
    index = pq.read_table(keyframe_root / "logs" / "index.parquet").to_pydict()
    assert index["frame"] == [0, 5, 10, 15, 20, 25, 30, 35]


def test_validation_names_a_missing_state_frame(keyframe_root: Path, tmp_path: Path) -> None:
    """A sensor topic between keyframes is as wrong as a state topic missing at one."""
    with LogReader(_log(keyframe_root)) as log:
        log.sensor_every = 1  # read as if every frame should hold the sensors
        with pytest.raises(LogFormatError, match=r"has 0 messages at frame 1 .*expected 1"):
            log.validate()


def test_the_dataset_serves_a_keyframe_log_as_a_10hz_logs_keyframes(
    loader_root: Path, keyframe_root: Path
) -> None:
    everything = DriveE2EDataset(loader_root, "test", frame_stride=5, with_lidar=True)
    keyframes = DriveE2EDataset(keyframe_root, "test", frame_stride=5, with_lidar=True)
    assert (
        keyframes.samples
        == everything.samples
        == [(everything.samples[0][0], f) for f in range(0, LONG_CLIP_FRAMES, 5)]
    )
    # frame_stride counts 10 Hz frames: 1 serves every keyframe, 10 every other one
    assert DriveE2EDataset(keyframe_root, "test", frame_stride=1).samples == keyframes.samples
    assert [f for _, f in DriveE2EDataset(keyframe_root, "test", frame_stride=10).samples] == [
        0, 10, 20, 30,
    ]  # fmt: skip
    for index in (0, 3, len(keyframes) - 1):
        ours, theirs = keyframes[index], everything[index]
        assert ours.keys() == theirs.keys()
        for key, value in theirs.items():
            if torch.is_tensor(value):
                assert torch.equal(ours[key], value), key
            else:
                assert ours[key] == value, key
    # the future trajectory of frame 0 reaches 3 s: six 2 Hz steps, all there
    assert bool(keyframes[0]["gt_ego_fut_masks"].all())
    assert np.abs(keyframes[0]["gt_ego_fut_trajs"].numpy()).sum() > 0


def test_queues_and_exports_must_fall_on_keyframes(keyframe_root: Path) -> None:
    queued = DriveE2EDataset(keyframe_root, "test", queue_length=3, queue_stride_frames=5)
    assert queued[1]["queue_valid"].tolist() == [False, True, True]  # frame 5: 0 and 5 exist
    with pytest.raises(DriveE2EError, match="queue_stride_frames=3 must be a multiple of it"):
        DriveE2EDataset(keyframe_root, "test", queue_length=3, queue_stride_frames=3)
    with pytest.raises(DriveE2EError, match="sensor data at every 5th frame only"):
        common.keyframes(0, LONG_CLIP_FRAMES, 2, 5)
    assert common.keyframes(0, LONG_CLIP_FRAMES, 10, 5) == [0, 10, 20, 30]
