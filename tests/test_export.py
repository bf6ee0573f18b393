"""Exports: the official nuscenes-devkit loads the nuScenes layout and renders it; the info
pickle carries VAD's keys for every sample."""

from __future__ import annotations

import json
import os
import pickle
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from drivee2e_data.cli import main
from drivee2e_data.export.infos import INFO_KEYS
from drivee2e_data.loaders import DriveE2EDataset

REPOSITORY = Path(__file__).resolve().parents[1]
DEVKIT_PYTHON = REPOSITORY / ".venv-nuscenes" / "bin" / "python"


@pytest.fixture(scope="module")
def exported(loader_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("export") / "nuscenes"
    assert main(["export", "nuscenes", str(loader_root), "--out", str(out)]) == 0
    return out


def test_devkit_loads_the_export_and_renders_boxes(
    loader_root: Path, exported: Path, tmp_path: Path
) -> None:
    if not DEVKIT_PYTHON.is_file():
        if os.environ.get("CI"):
            pytest.fail(f"{DEVKIT_PYTHON} is missing: scripts/test.sh installs the devkit")
        pytest.skip("the nuscenes-devkit environment is absent (bash scripts/test.sh makes it)")
    script = REPOSITORY / "scripts" / "check_nuscenes_export.py"
    result = subprocess.run(
        [
            str(DEVKIT_PYTHON),
            str(script),
            str(exported),
            "v1.0-drivee2e",
            str(tmp_path),
            "--sample",
            "2",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    # 4 clips -> 4 scenes; keyframes every 5th frame: 36 -> 8, 6 -> 2, 8 -> 2, 8 -> 2
    scenes = DriveE2EDataset(loader_root, "all", cameras=()).log_info.keys()
    assert sorted(summary["scenes"]) == sorted(scenes)
    assert summary["tables"]["sample"] == 14
    assert summary["tables"]["sample_data"] == 14 * 7
    assert summary["camera_boxes"], "the rendered front camera shows boxes"
    with_boxes = cv2.imread(str(tmp_path / "camera.png"))[:, :, ::-1].astype(int)
    plain = cv2.imread(str(tmp_path / "camera_plain.png"))[:, :, ::-1].astype(int)
    assert with_boxes.shape == plain.shape
    changed = np.abs(with_boxes - plain).sum(-1) > 30
    assert changed.sum() > 100  # box lines drawn
    colours = np.array(list(summary["colours"].values()))
    drawn = with_boxes[changed]
    near = np.min(np.abs(drawn[:, None, :] - colours[None]).sum(-1), axis=1) < 40
    assert near.mean() > 0.5  # most drawn pixels carry a category's colour


def test_export_refuses_an_existing_folder(loader_root: Path, exported: Path, capsys) -> None:
    assert main(["export", "nuscenes", str(loader_root), "--out", str(exported)]) == 2
    assert "already exists" in capsys.readouterr().err


def test_info_pickle_has_every_key_for_every_sample(
    loader_root: Path, exported: Path, tmp_path: Path
) -> None:
    out = tmp_path / "infos_test.pkl"
    args = [
        "export",
        "infos",
        str(loader_root),
        "--out",
        str(out),
        "--split",
        "test",
        "--nuscenes",
        str(exported),
    ]
    assert main(args) == 0
    with open(out, "rb") as stream:
        document = pickle.load(stream)
    assert document["metadata"] == {"version": "v1.0-drivee2e"}
    infos = document["infos"]
    assert len(infos) == 8  # the 36-frame test clip at 2 Hz
    for info in infos:
        assert set(INFO_KEYS) <= set(info)
        count = len(info["gt_names"])
        assert info["gt_boxes"].shape == (count, 7)
        assert info["gt_agent_fut_trajs"].shape == (count, 12)
        assert info["gt_ego_fut_trajs"].shape == (6, 2) and info["gt_ego_his_trajs"].shape == (2, 2)
        assert info["gt_map_pts"].shape[1:] == (20, 2)
        assert len(info["gt_map_pts"]) == len(info["gt_map_labels"]) > 0
        assert np.abs(info["gt_map_pts"][..., 0]).max() <= 15.0 + 1e-4  # across: nuScenes x
        assert np.abs(info["gt_map_pts"][..., 1]).max() <= 30.0 + 1e-4
        assert Path(info["lidar_path"]).is_file()
        assert all(Path(cam["data_path"]).is_file() for cam in info["cams"].values())
    # the straight clip drives forward: in nuScenes' LiDAR axes that is +y, at the log's speed
    dataset = DriveE2EDataset(loader_root, "test", cameras=(), frame_stride=5)
    for info, index in zip(infos, range(len(dataset)), strict=True):
        sample = dataset[index]
        mask = info["gt_ego_fut_masks"].astype(bool)
        steps = info["gt_ego_fut_trajs"][mask]
        assert np.allclose(steps[:, 0], 0.0, atol=1e-3)
        positions = np.cumsum(info["gt_ego_fut_trajs"], axis=0)[mask]
        # the map labels are the Dataset's, turned into nuScenes' axes (x right, y forward)
        mine = sample["gt_map_pts"].double().numpy()
        turned = np.stack([-mine[..., 1], mine[..., 0]], -1)
        ours = sorted(map(tuple, np.round(turned.reshape(len(turned), -1), 2)))
        theirs = sorted(map(tuple, np.round(info["gt_map_pts"].reshape(len(turned), -1), 2)))
        assert np.allclose(ours, theirs, atol=0.02)
        assert np.allclose(
            positions[:, 1], sample["gt_ego_fut_trajs"][mask][:, 0].numpy(), atol=1e-3
        )
        assert info["prev"] == (infos[index - 1]["token"] if index else "")


def test_map_masks_put_every_ego_pose_on_the_road(exported: Path) -> None:
    """nuScenes map masks: 0.1 m pixels, the global origin at the lower-left corner."""
    tables = exported / "v1.0-drivee2e"
    logs = {r["token"]: r for r in json.loads((tables / "log.json").read_text())}
    maps = {t: r for r in json.loads((tables / "map.json").read_text()) for t in r["log_tokens"]}
    scenes = {r["token"]: r for r in json.loads((tables / "scene.json").read_text())}
    samples = json.loads((tables / "sample.json").read_text())
    sample_data = json.loads((tables / "sample_data.json").read_text())
    poses = {r["token"]: r for r in json.loads((tables / "ego_pose.json").read_text())}
    pose_of = {d["sample_token"]: poses[d["ego_pose_token"]] for d in sample_data}
    on_road = 0
    for sample in samples:
        log_token = scenes[sample["scene_token"]]["log_token"]
        mask = cv2.imread(str(exported / maps[log_token]["filename"]), cv2.IMREAD_GRAYSCALE)
        x, y, _ = pose_of[sample["token"]]["translation"]
        assert min(x, y) > 0 and logs[log_token]["drivee2e_global_offset_m"][0] > 0
        on_road += int(mask[mask.shape[0] - 1 - int(y / 0.1), int(x / 0.1)] == 255)
    assert on_road == len(samples)
