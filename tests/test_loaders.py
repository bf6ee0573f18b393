"""The torch Dataset, collate and data module over collected logs (the `loader_root` set)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import copy_clips
from torch.utils.data import DataLoader

from drivee2e_data import store
from drivee2e_data.cli import main
from drivee2e_data.errors import DriveE2EError, LogFormatError
from drivee2e_data.loaders import (
    CLASSES,
    DriveE2EDataModule,
    DriveE2EDataset,
    collate,
    decode_jpegs,
)
from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader

LIDAR_MOUNT = np.array([0.95, 0.0, 1.85])


def test_every_split_iterates_through_a_dataloader(loader_root: Path) -> None:
    sizes = {}
    for split in ("train", "val", "test"):
        dataset = DriveE2EDataset(loader_root, split, image_size=(80, 45))
        loader = DataLoader(dataset, batch_size=4, num_workers=2, collate_fn=collate, timeout=120)
        seen = 0
        for batch in loader:
            assert batch["img"].shape[1:] == (6, 3, 45, 80)
            assert batch["img"].dtype == torch.uint8
            assert batch["gt_boxes"].shape[:2] == batch["gt_boxes_mask"].shape
            seen += len(batch["scene_token"])
        sizes[split] = seen
    assert sizes == {"train": 14, "val": 8, "test": 36}


def test_fields_shapes_dtypes_and_frames_against_the_log(loader_root: Path) -> None:
    dataset = DriveE2EDataset(loader_root, "test", with_lidar=True, with_radar=True)
    scenario_id, frame = dataset.samples[12]
    sample = dataset[12]
    assert (sample["scene_token"], sample["frame_idx"]) == (scenario_id, frame)
    with LogReader(loader_root / "logs" / f"{scenario_id}.mcap") as log:
        messages = log.frame(frame)
        future, future_mask = log.future_path(frame)
    state, imu = messages[topics.EGO_STATE], messages[topics.IMU]
    objects = list(messages[topics.OBJECTS].objects)
    expected = {
        "img": ((6, 3, 90, 160), torch.uint8),
        "cam_intrinsic": ((6, 3, 3), torch.float32),
        "cam2ego": ((6, 4, 4), torch.float32),
        "lidar2img": ((6, 4, 4), torch.float32),
        "lidar2ego": ((4, 4), torch.float64),
        "ego2global": ((4, 4), torch.float64),
        "gt_boxes": ((len(objects), 9), torch.float32),
        "gt_labels": ((len(objects),), torch.int64),
        "num_lidar_pts": ((len(objects),), torch.int64),
        "visibility": ((len(objects),), torch.int64),
        "gt_ego_his_trajs": ((4, 2), torch.float32),
        "gt_ego_fut_trajs": ((6, 2), torch.float32),
        "gt_ego_fut_masks": ((6,), torch.bool),
        "gt_ego_fut_cmd": ((3,), torch.float32),
        "ego_status": ((10,), torch.float32),
        "can_bus": ((18,), torch.float64),
        "gt_agent_fut_trajs": ((len(objects), 6, 2), torch.float32),
        "gt_agent_fut_masks": ((len(objects), 6), torch.bool),
        "traffic_light_state": ((4,), torch.float32),
        "target_point": ((2,), torch.float32),
        "radar_points": (None, torch.float32),
    }
    for key, (shape, dtype) in expected.items():
        assert sample[key].dtype == dtype, key
        if shape is not None:
            assert tuple(sample[key].shape) == shape, key
    # poses: ego2global is the logged rear-axle pose; lidar2ego the rig's mount
    assert np.allclose(sample["ego2global"][:3, 3].numpy(), [state.x, state.y, state.z])
    assert np.isclose(np.arctan2(*sample["ego2global"].numpy()[[1, 0], 0]), state.yaw)
    assert np.allclose(sample["lidar2ego"][:3, 3].numpy(), LIDAR_MOUNT)
    # boxes: the log's ego-frame centres less the LiDAR mount, the log's classes and counts
    by_id = {o.instance_id: o for o in objects}
    for k, instance in enumerate(sample["instance_ids"]):
        logged = by_id[instance]
        box = sample["gt_boxes"][k].double().numpy()
        assert np.allclose(
            box[:3], np.array([logged.ego_x, logged.ego_y, logged.ego_z]) - LIDAR_MOUNT, atol=1e-4
        )
        assert np.allclose(box[3:6], [logged.length, logged.width, logged.height], atol=1e-5)
        assert np.isclose(np.cos(box[6] - logged.ego_yaw), 1.0, atol=1e-6)
        assert np.allclose(box[7:9], [logged.ego_vx, logged.ego_vy], atol=1e-4)
        assert CLASSES[sample["gt_labels"][k]] == logged.category == sample["gt_names"][k]
        assert sample["num_lidar_pts"][k] == logged.num_lidar_points
        assert sample["visibility"][k] == logged.visibility
    # the 2 Hz future is the reader's, masks included; the status is the IMU's and the state's
    assert np.allclose(sample["gt_ego_fut_trajs"].numpy(), future, atol=1e-4)
    assert np.array_equal(sample["gt_ego_fut_masks"].numpy(), future_mask)
    status = sample["ego_status"].double().numpy()
    assert np.allclose(
        status[:3],
        [imu.linear_acceleration_x, imu.linear_acceleration_y, imu.linear_acceleration_z],
        atol=1e-4,
    )
    assert np.allclose(
        status[3:6],
        [imu.angular_velocity_x, imu.angular_velocity_y, imu.angular_velocity_z],
        atol=1e-5,
    )
    assert np.isclose(np.hypot(*status[6:8]), state.speed, atol=1e-4)
    assert np.isclose(status[9], state.steer, atol=1e-6)
    assert sample["gt_ego_fut_cmd"].argmax() + 1 == state.command
    assert np.allclose(sample["can_bus"][:3].numpy(), [state.x, state.y, state.z])
    assert np.isclose(sample["can_bus"][16], state.yaw) and np.isclose(
        sample["can_bus"][17], np.rad2deg(state.yaw)
    )
    # LiDAR: every logged point, in the LiDAR frame
    assert sample["points"].shape == (len(messages[topics.LIDAR].data) // 17, 5)
    assert sample["timestamp_ns"] == log.t_ns[frame - log.first_frame]


def test_straight_clip_future_is_straight(loader_root: Path) -> None:
    dataset = DriveE2EDataset(loader_root, "test", cameras=())
    assert (
        store.read_scenario(loader_root, dataset.samples[0][0]).behavior.sub_scenario.value == "STR"
    )
    for index in range(len(dataset)):
        sample = dataset[index]
        future = sample["gt_ego_fut_trajs"][sample["gt_ego_fut_masks"]]
        assert len(future) == min(6, (len(dataset) - 1 - index) // 5)  # masked past the log's end
        if not len(future):
            continue
        assert future[:, 1].abs().max() < 0.05
        assert torch.all(torch.diff(future[:, 0]) > 0)  # ever forward


def test_lidar2img_puts_box_centres_on_their_mask_pixels(loader_root: Path) -> None:
    """Each box centre, projected by the sample's lidar2img into an image, lands inside the
    pixels the camera's segmentation mask gives that box's body (their bounding rectangle)."""
    from drivee2e_data.sensors.camera import render
    from drivee2e_data.sensors.suite import SuiteOptions, configured_rig
    from drivee2e_data.sim.world import World

    dataset = DriveE2EDataset(loader_root, "test")
    scenario = store.read_scenario(loader_root, dataset.samples[0][0])
    rig = configured_rig(SuiteOptions(image_size=(160, 90)))
    checked = inside = 0
    with World(store.read_map(loader_root, scenario.map_id), scenario, renderer="auto") as world:
        for index in (0, 10, 20, 30):
            sample = dataset[index]
            frame = sample["frame_idx"]
            ego = scenario.ego
            world.place_ego(float(ego.x_m[frame]), float(ego.y_m[frame]), ego.track_id)
            world.set_time(frame)
            for c, camera in enumerate(rig.cameras):
                view = render(world, camera, sample["ego2global"].numpy(), mask=True)
                for k, instance in enumerate(sample["instance_ids"]):
                    rows, columns = np.nonzero(view.mask == world.bodies[instance])
                    if len(rows) < 20:
                        continue
                    centre = np.append(sample["gt_boxes"][k, :3].double().numpy(), 1.0)
                    u, v, depth, _ = sample["lidar2img"][c].double().numpy() @ centre
                    assert depth > 0, (instance, camera.name)
                    if not (0 <= u / depth < camera.width and 0 <= v / depth < camera.height):
                        continue  # cut by the image's edge: its centre is in another camera
                    checked += 1
                    inside += int(
                        columns.min() - 1 <= u / depth <= columns.max() + 1
                        and rows.min() - 1 <= v / depth <= rows.max() + 1
                    )
    assert checked >= 10
    assert inside == checked


def test_sample_is_the_same_in_a_worker(loader_root: Path) -> None:
    dataset = DriveE2EDataset(loader_root, "train", image_size=(80, 45), with_lidar=True)
    indices = [0, 5, 9]
    loader = DataLoader(
        torch.utils.data.Subset(dataset, indices), batch_size=None, num_workers=1, timeout=120
    )
    for index, from_worker in zip(indices, loader, strict=True):
        here = dataset[index]
        assert here.keys() == from_worker.keys()
        for key, value in here.items():
            if torch.is_tensor(value):
                assert torch.equal(value, from_worker[key]), key
            else:
                assert value == from_worker[key], key


def test_reduced_decode_scales_images_and_intrinsics(loader_root: Path) -> None:
    full = DriveE2EDataset(loader_root, "val")
    half = DriveE2EDataset(loader_root, "val", image_size=(80, 45))
    big, small = full[3], half[3]
    assert small["img"].shape == (6, 3, 45, 80)
    assert torch.allclose(small["cam_intrinsic"][:, :2], big["cam_intrinsic"][:, :2] / 2)
    # the half-size decode is the full image at half size, up to JPEG's scaled IDCT
    downsized = torch.nn.functional.avg_pool2d(big["img"].float(), 2)
    assert (downsized - small["img"].float()).abs().mean() < 6.0


def test_jpeg_bytes_decode_in_a_batch_to_the_same_images(loader_root: Path) -> None:
    decoded = DriveE2EDataset(loader_root, "val")
    raw = DriveE2EDataset(loader_root, "val", decode="none")
    batch = collate([raw[0], raw[1]])
    assert len(batch["img_jpeg"]) == 2 and len(batch["img_jpeg"][0]) == 6
    batch = decode_jpegs(batch, (160, 90), None, device="cpu")
    assert torch.equal(batch["img"], collate([decoded[0], decoded[1]])["img"])


def test_queue_gives_earlier_frames_oldest_first(loader_root: Path) -> None:
    dataset = DriveE2EDataset(loader_root, "test", queue_length=3, queue_stride_frames=5)
    sample = dataset[12]
    assert sample["img"].shape == (3, 6, 3, 90, 160)
    assert sample["ego2global"].shape == (3, 4, 4)
    assert sample["queue_valid"].tolist() == [True, True, True]
    times = sample["timestamp_ns"].tolist()
    assert times[1] - times[0] == times[2] - times[1] == 500_000_000
    assert torch.equal(sample["ego2global"][-1], dataset[12]["ego2global"][-1])
    first = dataset[0]
    assert first["queue_valid"].tolist() == [False, False, True]


def test_collate_pads_boxes_and_keeps_lists(loader_root: Path) -> None:
    dataset = DriveE2EDataset(loader_root, "test", cameras=(), with_lidar=True)
    samples = [dataset[0], dataset[30]]
    batch = collate(samples)
    most = max(len(s["gt_labels"]) for s in samples)
    assert batch["gt_boxes"].shape == (2, most, 9)
    for k, s in enumerate(samples):
        count = len(s["gt_labels"])
        assert batch["gt_boxes_mask"][k].sum() == count
        assert torch.equal(batch["gt_boxes"][k, :count], s["gt_boxes"])
        assert not batch["gt_boxes"][k, count:].any()
        assert batch["instance_ids"][k] == s["instance_ids"]
    assert isinstance(batch["points"], list) and len(batch["points"]) == 2
    assert batch["timestamp"].dtype == torch.float64


def test_data_module_serves_each_split(loader_root: Path) -> None:
    module = DriveE2EDataModule(loader_root, batch_size=3, num_workers=0, cameras=("CAM_FRONT",))
    module.setup("fit")
    train = next(iter(module.train_dataloader()))
    assert train["img"].shape[:2] == (3, 1)
    assert sum(len(b["scene_token"]) for b in module.val_dataloader()) == 8
    assert sum(len(b["scene_token"]) for b in module.test_dataloader()) == 36


@pytest.mark.slow
def test_loaders_do_not_import_the_simulator() -> None:
    code = (
        "import sys, drivee2e_data.loaders, drivee2e_data.metrics.openloop, drivee2e_data.export.nuscenes;"
        "bad = [m for m in sys.modules if m.startswith(('pybullet', 'drivee2e_data.sim', 'drivee2e_data.sensors.suite'))];"
        "print(bad); sys.exit(1 if bad else 0)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_the_agents_and_the_cache_do_not_import_the_data_module() -> None:
    """A closed-loop worker builds its agent (which imports the feature cache and the Dataset)
    without the Lightning data module or torchmetrics: Lightning, where installed, imports
    torchmetrics and torchvision (8.7 s a worker on an H100-class host; the constant-velocity
    agent's import of the open-loop metric cost each worker 10 s on a 4-GPU host). The data
    module still comes on use."""
    code = (
        "import sys, drivee2e_data.agents.tcp, drivee2e_data.agents.camera, drivee2e_data.loaders;"
        "import drivee2e_data.agents.admlp, drivee2e_data.agents.constant_velocity;"
        "import drivee2e_data.agents.expert;"
        "bad = [m for m in sys.modules if m.startswith(('lightning', 'pytorch_lightning',"
        " 'torchmetrics', 'drivee2e_data.loaders.datamodule'))];"
        "from drivee2e_data.loaders import DriveE2EDataModule;"
        "print(bad, DriveE2EDataModule.__name__); sys.exit(1 if bad else 0)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "DriveE2EDataModule" in result.stdout


def _root_with(loader_root: Path, tmp_path: Path) -> Path:
    root = tmp_path / "data"
    shutil.copytree(loader_root, root)
    return root


def test_missing_log_is_named_with_its_split(loader_root: Path, tmp_path: Path) -> None:
    root = _root_with(loader_root, tmp_path)
    victim = DriveE2EDataset(root, "val", cameras=()).samples[0][0]
    (root / "logs" / f"{victim}.mcap").unlink()
    with pytest.raises(
        DriveE2EError, match=rf"default.csv: clip '{victim}' \(val\) has no collected log"
    ):
        DriveE2EDataset(root, "val")


def test_truncated_log_is_named(loader_root: Path, tmp_path: Path) -> None:
    root = _root_with(loader_root, tmp_path)
    victim = DriveE2EDataset(root, "val", cameras=()).samples[0][0]
    path = root / "logs" / f"{victim}.mcap"
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(LogFormatError, match=str(path)):
        DriveE2EDataset(root, "val")


def test_damaged_log_fails_a_worker_with_its_name_not_a_hang(
    loader_root: Path, tmp_path: Path
) -> None:
    root = _root_with(loader_root, tmp_path)
    dataset = DriveE2EDataset(root, "val", image_size=(80, 45))
    path = root / "logs" / f"{dataset.samples[0][0]}.mcap"
    data = bytearray(path.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 200_000] = bytes(200_000)  # chunks in the middle become garbage
    path.write_bytes(bytes(data))
    loader = DataLoader(dataset, batch_size=2, num_workers=2, collate_fn=collate, timeout=120)
    with pytest.raises(Exception, match=str(path.name)):
        for _ in loader:
            pass


def test_unknown_split_and_camera_are_refused(loader_root: Path) -> None:
    with pytest.raises(ValueError, match="split 'training'"):
        DriveE2EDataset(loader_root, "training")
    with pytest.raises(DriveE2EError, match="no frame index"):
        DriveE2EDataset(
            loader_root / "nothing", "train", split_name=str(loader_root / "splits" / "default.csv")
        )


@pytest.mark.slow
def test_committed_quickstart_manifest_is_what_split_makes(
    synthetic_root: Path, tmp_path: Path
) -> None:
    committed = Path(__file__).resolve().parents[1] / "splits" / "quickstart.csv"
    ids = [f"synth_s0_c{k:04d}" for k in range(4)]  # the quickstart's four clips
    root = copy_clips(synthetic_root, tmp_path / "data", ids)
    assert main(["split", str(root), "--seed", "0"]) == 0
    assert (root / "splits" / "default.csv").read_bytes() == committed.read_bytes()


def test_data_module_drives_a_lightning_fit(loader_root: Path, tmp_path: Path) -> None:
    """With Lightning installed the module is a LightningDataModule: a Trainer fits through it,
    and JPEG bytes (decode="none") arrive decoded on the training device."""
    lightning = pytest.importorskip("lightning.pytorch")
    module = DriveE2EDataModule(
        loader_root, batch_size=2, num_workers=0, cameras=("CAM_FRONT",), decode="none"
    )
    assert isinstance(module, lightning.LightningDataModule)
    seen: list[tuple[int, ...]] = []

    class Planner(lightning.LightningModule):
        def __init__(self) -> None:
            super().__init__()
            self.layer = torch.nn.Linear(10, 12)

        def training_step(self, batch, batch_index):  # type: ignore[no-untyped-def]
            seen.append(tuple(batch["img"].shape))
            plan = self.layer(batch["ego_status"]).reshape(-1, 6, 2)
            return (plan - batch["gt_ego_fut_trajs"]).abs().mean()

        def configure_optimizers(self):  # type: ignore[no-untyped-def]
            return torch.optim.SGD(self.parameters(), lr=1e-3)

    trainer = lightning.Trainer(
        max_epochs=1,
        accelerator="cpu",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        limit_val_batches=0,
        default_root_dir=tmp_path,
    )
    trainer.fit(Planner(), datamodule=module)
    assert seen and all(shape[1:] == (1, 3, 90, 160) for shape in seen)
    assert sum(shape[0] for shape in seen) == 14  # every train sample once


def test_distributed_sampler_splits_the_samples_between_ranks(loader_root: Path) -> None:
    from torch.utils.data import DistributedSampler

    dataset = DriveE2EDataset(loader_root, "train", cameras=())
    seen = []
    for rank in (0, 1):
        sampler = DistributedSampler(dataset, num_replicas=2, rank=rank, shuffle=True, seed=4)
        loader = DataLoader(
            dataset, batch_size=3, sampler=sampler, num_workers=1, collate_fn=collate, timeout=120
        )
        seen.append(
            [
                (scene, frame)
                for b in loader
                for scene, frame in zip(b["scene_token"], b["frame_idx"].tolist(), strict=True)
            ]
        )
    assert len(seen[0]) == len(seen[1]) == 7
    assert not set(seen[0]) & set(seen[1])
    assert set(seen[0]) | set(seen[1]) == set(dataset.samples)


def test_map_labels_lie_on_the_map_inside_the_patch(loader_root: Path) -> None:
    import shapely

    from drivee2e_data.loaders.map_labels import MAP_CLASSES

    dataset = DriveE2EDataset(
        loader_root, "test", cameras=(), map_patch_m=(60.0, 30.0), map_points=20
    )
    intersection_map = store.read_map(
        loader_root, dataset.log_info[dataset.samples[0][0]]["map_id"]
    )
    crossings = [shapely.Polygon(c.polygon_m[:, :2]).exterior for c in intersection_map.crosswalks]
    lane_lines = [
        shapely.LineString(side[:, :2])
        for lane in intersection_map.lanes
        for side in (lane.left_boundary_m, lane.right_boundary_m)
    ]
    seen = set()
    for index in (0, 15, 30):
        sample = dataset[index]
        points, classes = sample["gt_map_pts"].double().numpy(), sample["gt_map_labels"].numpy()
        assert points.shape[1:] == (20, 2) and len(points) == len(classes) > 0
        assert (
            np.abs(points[..., 0]).max() <= 30.0 + 1e-6
            and np.abs(points[..., 1]).max() <= 15.0 + 1e-6
        )
        lidar_to_world = (sample["ego2global"] @ sample["lidar2ego"]).numpy()
        for line, label in zip(points, classes, strict=True):
            world = line @ lidar_to_world[:2, :2].T + lidar_to_world[:2, 3]
            name = MAP_CLASSES[label]
            seen.add(name)
            spots = shapely.MultiPoint(world)
            if name == "ped_crossing":
                assert min(ring.distance(spots) for ring in crossings) < 1e-6
                assert (
                    max(min(r.distance(shapely.Point(p)) for r in crossings) for p in world) < 1e-6
                )
            else:  # dividers and the road's edge run along lane boundaries
                assert (
                    max(min(edge.distance(shapely.Point(p)) for edge in lane_lines) for p in world)
                    < 0.05
                )
            spacing = np.linalg.norm(np.diff(line, axis=0), axis=1)
            assert np.allclose(spacing, spacing.mean(), rtol=0.05, atol=1e-3)  # evenly resampled
    assert {"divider", "boundary"} <= seen
    # on the straight approach the dividers run along the ego's heading
    first = dataset[0]
    dividers = first["gt_map_pts"][first["gt_map_labels"] == MAP_CLASSES.index("divider")]
    assert len(dividers) >= 1
    assert (dividers[:, -1, 1] - dividers[:, 0, 1]).abs().max() < 0.1


def test_map_labels_need_the_map_or_say_so(loader_root: Path, tmp_path: Path) -> None:
    root = _root_with(loader_root, tmp_path)
    for path in (root / "maps").glob("*.json"):
        path.unlink()
    with pytest.raises(DriveE2EError, match=r"is missing .*with_map=False"):
        DriveE2EDataset(root, "val")
    sample = DriveE2EDataset(root, "val", cameras=(), with_map=False)[0]
    assert "gt_map_pts" not in sample


def test_bev_segmentation_agrees_with_the_map(loader_root: Path) -> None:
    import shapely

    from drivee2e_data.loaders.map_labels import map_elements

    dataset = DriveE2EDataset(loader_root, "test", cameras=(), bev_seg=(160, 1.0))
    sample = dataset[35]  # the junction and its crosswalks ahead
    layers = sample["gt_bev_seg"].numpy()
    assert layers.shape == (3, 160, 160) and layers.dtype == np.uint8
    assert layers[0, 80, 80] == 1  # the LiDAR stands on the road
    intersection_map = store.read_map(
        loader_root, dataset.log_info[dataset.samples[0][0]]["map_id"]
    )
    elements = map_elements(intersection_map)
    crossings = shapely.union_all([shapely.Polygon(c) for c in elements.crosswalks_m])
    # pixel centres back in the world: row 0 is 80 m ahead, column 0 is 80 m to the left
    rows, columns = np.mgrid[0:160, 0:160]
    local = np.stack([80.0 - rows - 0.5, 80.0 - columns - 0.5], -1).reshape(-1, 2)
    pose = (sample["ego2global"] @ sample["lidar2ego"]).numpy()
    world = local @ pose[:2, :2].T + pose[:2, 3]
    on_road = shapely.contains_xy(elements.road, world[:, 0], world[:, 1]).reshape(160, 160)
    on_crossing = shapely.contains_xy(crossings, world[:, 0], world[:, 1]).reshape(160, 160)
    assert on_road.sum() > 500 and on_crossing.sum() > 10
    assert (layers[0] == on_road).mean() > 0.97  # only pixels on the road's edge may differ
    assert (layers[2] == on_crossing).mean() > 0.99
    assert layers[1].sum() > 50  # lane lines drawn


def test_traffic_light_field_is_the_signal_binding_the_ego_at_each_frame(
    loader_root: Path,
) -> None:
    """The log's light per frame is the state of `binding_signals`' signal, worked out here
    from the clip's scenario and map alone; the Dataset's one-hot field agrees."""
    from drivee2e_data.binding import binding_signals, front_bumper
    from drivee2e_data.loaders.clip import LIGHT_STATES, read_clip
    from drivee2e_data.scenario import SignalState

    checked = bound_frames = 0
    for scenario_id in store.scenario_ids(loader_root):
        scenario = store.read_scenario(loader_root, scenario_id)
        intersection_map = store.read_map(loader_root, scenario.map_id)
        ego = scenario.ego
        front = front_bumper(ego.xy_m, ego.yaw_rad, float(np.median(ego.length_m)))
        bound = binding_signals(intersection_map, scenario.route.lane_ids, front)
        states = {s.signal_id: s.states for s in scenario.signals}
        with LogReader(loader_root / "logs" / f"{scenario_id}.mcap") as log:
            clip = read_clip(log)
        for row in range(len(clip.t_ns)):
            frame = clip.first_frame + row
            name = "NONE"
            if bound[frame] is not None:
                name = SignalState(int(states[bound[frame]][frame])).name
                bound_frames += 1
            expected = LIGHT_STATES.index(name if name in LIGHT_STATES[:3] else "NONE")
            assert clip.ego_light[row] == expected, (scenario_id, frame)
            checked += 1
    assert checked >= 50 and bound_frames >= 10  # the clips' first frames: before their lines
    dataset = DriveE2EDataset(loader_root, "test")
    scenario_id, frame = dataset.samples[0]
    with LogReader(loader_root / "logs" / f"{scenario_id}.mcap") as log:
        clip = read_clip(log)
    one_hot = dataset[0]["traffic_light_state"]
    assert int(one_hot.argmax()) == clip.ego_light[frame - clip.first_frame]
    assert float(one_hot.sum()) == 1.0
