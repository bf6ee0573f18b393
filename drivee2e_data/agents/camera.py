"""A small camera policy: the three front cameras at low resolution, the high-level command,
the speed and the route's target point, to the 2 Hz waypoints (a TCP-like trajectory branch
without its control branch). Trainable on a CPU in minutes: `drivee2e train camera DATA`.

Images go through the Dataset's own decoder (JPEG reduced in the DCT, then area-resized), in
training and in closed loop alike, so the policy sees the same pixels in both.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from drivee2e_data.agents import checkpoint as checkpoints
from drivee2e_data.agents import training
from drivee2e_data.agents.device import agent_device
from drivee2e_data.agents.inference import NetworkRunner
from drivee2e_data.agents.training import TrainOptions, fit
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.evaluate.agent import Observation, Route, Waypoints
from drivee2e_data.loaders.cache import EGO_FIELDS, FeatureCache, FeatureSpec
from drivee2e_data.loaders.dataset import DriveE2EDataset
from drivee2e_data.loaders.images import decode_cpu
from drivee2e_data.sensors.rig import Rig

FRONT_CAMERAS = ("CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT")
INPUT_SIZE = (128, 72)  # width, height fed to the network
# what the policy reads, declared once: its training cache and its closed-loop cameras
FEATURES = FeatureSpec("camera", EGO_FIELDS, FRONT_CAMERAS, INPUT_SIZE)
SPEED_SCALE_MPS = 10.0
TARGET_SCALE_M = 20.0
PIXEL_MEAN, PIXEL_STD = 0.45, 0.25


class CameraPolicy(nn.Module):
    """A small convolutional encoder shared by the cameras, globally pooled and squeezed to 16
    features with dropout, beside command (3), speed (1) and target point (2), through an MLP
    to `steps` waypoints. Small on purpose: with a few dozen training clips a larger image
    branch memorises each clip's look and drives worse (docs/results.md)."""

    name = "camera"

    def __init__(self, cameras: int = 3, steps: int = 6) -> None:
        super().__init__()
        self.steps = steps

        def block(inputs: int, outputs: int) -> nn.Sequential:
            return nn.Sequential(
                nn.Conv2d(inputs, outputs, 3, 2, 1), nn.BatchNorm2d(outputs), nn.ReLU()
            )

        self.encoder = nn.Sequential(
            block(3, 16), block(16, 24), block(24, 32), block(32, 32),
            nn.AdaptiveAvgPool2d(1), nn.Flatten(),
        )  # fmt: skip
        self.squeeze = nn.Sequential(
            nn.Dropout(0.5), nn.Linear(cameras * 32, 16), nn.ReLU(), nn.Dropout(0.3)
        )
        self.head = nn.Sequential(
            nn.Linear(16 + 6, 256), nn.ReLU(), nn.Linear(256, 256), nn.ReLU(),
            nn.Linear(256, steps * 2),
        )  # fmt: skip
        # training draws a brightness gain per image from this counter: saved with the weights,
        # so a resumed training draws what an uninterrupted one would
        self.register_buffer("augment_step", torch.zeros((), dtype=torch.int64))
        self.register_load_state_dict_post_hook(forget_host_counter)

    def forward(self, images: torch.Tensor, vector: torch.Tensor) -> torch.Tensor:
        """images: (B, K, 3, H, W) uint8; vector: (B, 6) command one-hot, speed, target."""
        batch, cameras = images.shape[:2]
        pixels = images.flatten(0, 1).float() / 255.0
        if self.training:
            gain = brightness_gains(self, batch, pixels.device).view(batch, 1, 1, 1, 1)
            pixels = (pixels.view(batch, cameras, *pixels.shape[1:]) * gain).clamp(0.0, 1.0)
            pixels = pixels.flatten(0, 1)
        features = self.encoder((pixels - PIXEL_MEAN) / PIXEL_STD).view(batch, -1)
        return self.head(torch.cat([self.squeeze(features), vector], 1)).view(batch, self.steps, 2)


def brightness_gains(model: nn.Module, count: int, device: torch.device) -> torch.Tensor:
    """`count` brightness gains in [0.7, 1.3] on `device`, drawn from a generator seeded with
    the model's step counter (its `augment_step` buffer, saved with the weights: a resumed
    training draws what an uninterrupted one would); the counter then advances by one.

    The counter's value is also kept on the host (read from the buffer once, and again after
    each `load_state_dict`: `forget_host_counter`), and the gains reach a GPU from pinned memory
    without waiting: reading the buffer, or copying from pageable memory, made every training
    step on a GPU wait for the one before it to finish."""
    step = model.__dict__.get("_augment_host")
    if step is None:
        step = int(model.augment_step)
    model.__dict__["_augment_host"] = step + 1
    model.augment_step += 1
    gains = torch.empty(count).uniform_(0.7, 1.3, generator=torch.Generator().manual_seed(step))
    if device.type == "cuda":
        return gains.pin_memory().to(device, non_blocking=True)
    return gains.to(device)


def forget_host_counter(model: nn.Module, incompatible: Any) -> None:
    """A `load_state_dict` post-hook: the host's copy of the augmentation counter is read from
    the loaded buffer at the next draw."""
    del incompatible
    model.__dict__.pop("_augment_host", None)


def vector_features(
    command_one_hot: torch.Tensor, speed_mps: torch.Tensor, target_m: torch.Tensor
) -> torch.Tensor:
    """(B, 6): command one-hot (3), speed / 10 m/s, target point / 20 m."""
    return torch.cat(
        [
            command_one_hot.float(),
            speed_mps.float().view(-1, 1) / SPEED_SCALE_MPS,
            target_m.float().view(-1, 2) / TARGET_SCALE_M,
        ],
        1,
    )


def dataset_for(
    root: Path, split: str, split_name: str = "default", input_size: tuple[int, int] = INPUT_SIZE
) -> DriveE2EDataset:
    """The split's samples as a front-camera policy reads them (the three front cameras at
    `input_size`, width and height)."""
    return DriveE2EDataset(
        root, split, split_name, cameras=FRONT_CAMERAS, image_size=input_size, with_map=False
    )


def batch_vector(batch: dict[str, Any]) -> torch.Tensor:
    """A Dataset batch's measurement vector (`vector_features`)."""
    return vector_features(
        batch["gt_ego_fut_cmd"], batch["ego_status"][:, 6], batch["target_point"]
    )


def observation_inputs(
    observation: Observation, image_size: tuple[int, int], input_size: tuple[int, int]
) -> tuple[torch.Tensor, torch.Tensor]:
    """A closed-loop observation as a front-camera policy's batch of one: the front cameras at
    `input_size` `(1, 3, 3, H, W)` uint8 (drawn at that size, `Observation.pixels`, or their
    JPEGs collected at `image_size` decoded as the Dataset decodes them), and the measurement
    vector `(1, 6)`."""
    if observation.pixels:
        images = np.stack([observation.pixels[c] for c in FRONT_CAMERAS])
    else:
        images = np.stack(
            [decode_cpu(observation.images[c], image_size, input_size) for c in FRONT_CAMERAS]
        )
    command = torch.zeros(1, 3)
    command[0, int(observation.command) - 1] = 1.0
    vector = vector_features(
        command,
        torch.tensor([observation.speed_mps]),
        torch.as_tensor(np.asarray(observation.target_point_m), dtype=torch.float32),
    )
    return torch.from_numpy(images)[None], vector


def example_inputs(input_size: tuple[int, int]) -> dict[str, np.ndarray]:
    """A front-camera policy's inputs of one observation at `input_size` (width, height) as its
    agent's `model_inputs` gives them (`observation_inputs`), all zeros: what a policy server
    runs once before its first request (`policy_server.warm_up`)."""
    width, height = input_size
    return {"images": np.zeros((len(FRONT_CAMERAS), 3, height, width), np.uint8),
            "vector": np.zeros(6, np.float32)}  # fmt: skip


def trainable_size(
    dataset: DriveE2EDataset | FeatureCache, input_size: tuple[int, int], name: str
) -> list[int]:
    """The full camera size of `dataset`'s logs, once it is checked to hold samples of the
    front cameras at `input_size` (`dataset_for`, or the policy's feature cache), for policy
    `name`."""
    if len(dataset) == 0:
        raise DriveE2EError(
            f"{dataset.manifest}: split {dataset.split!r} has no samples to train on"
        )
    if isinstance(dataset, FeatureCache):
        cameras, image_size = dataset.spec.cameras, dataset.spec.image_size
    else:
        cameras, image_size = tuple(dataset.cameras), dataset.image_size
    if cameras != FRONT_CAMERAS or image_size != input_size:
        raise DriveE2EError(f"the {name} policy trains on {name}.dataset_for(...) samples")
    if isinstance(dataset, FeatureCache):
        return list(dataset.camera_full_size())
    first = dataset.samples[0][0]
    return list(dataset.log_info[first]["cameras"][FRONT_CAMERAS[1]]["full_size"])


def inputs(batch: dict[str, Any]) -> dict[str, torch.Tensor]:
    """The policy's inputs of a batch: the front images and the measurement vector."""
    return {"images": batch["img"], "vector": batch_vector(batch)}


def extract(
    dataset: DriveE2EDataset, progress: Callable[[int], None] | None = None
) -> dict[str, torch.Tensor]:
    """Images, vector features, targets `y` and masks of every sample, in dataset order."""
    return training.extract(dataset, inputs, 64, progress)


def train(
    dataset: DriveE2EDataset | FeatureCache,
    checkpoint: Path,
    options: TrainOptions | None = None,
    on_epoch: Callable[[int, float], None] | None = None,
    on_sample: Callable[[int], None] | None = None,
    device: str = "cpu",
) -> dict[str, Any]:
    """Train on every sample of `dataset` (from `dataset_for`, or the split's feature cache of
    `FEATURES`); returns the checkpoint."""
    options = options or TrainOptions(epochs=40, batch_size=32)
    full_size = trainable_size(dataset, INPUT_SIZE, CameraPolicy.name)
    data = training.source(dataset, inputs, 64, on_sample)
    torch.manual_seed(options.seed)
    model = CameraPolicy(len(FRONT_CAMERAS), int(data.rows(torch.arange(1))["y"].shape[1]))
    header = {"kind": CameraPolicy.name, "steps": model.steps, "camera_size": full_size}
    gpu = torch.device(device).type == "cuda"
    return fit(
        model,
        data,
        lambda m, rows: m(rows["images"], rows["vector"]),
        checkpoint,
        options,
        header,
        on_epoch,
        device,
        mixed_precision=gpu,
    )


def load(path: Path, network: bool = True) -> tuple[CameraPolicy | None, tuple[int, int]]:
    """The trained policy (None without `network`) and the camera image size its data was
    collected at."""
    saved = checkpoints.load(path, CameraPolicy.name, "drivee2e train camera")
    width, height = saved["camera_size"]
    if not network:
        return None, (int(width), int(height))
    model = CameraPolicy(len(FRONT_CAMERAS), saved["steps"])
    model.load_state_dict(saved["model"])
    model.eval()
    return model, (int(width), int(height))


class FrontCameraAgent:
    """A policy of the front cameras in closed loop: the cameras as its training read them
    (`sensors`, `input_size`: its `FeatureSpec`), drawn for the size its data was collected at
    and served at its input size (`evaluate/observation.py`); waypoints to the harness's
    controllers. The network, read from the checkpoint by `load` (the policy, None without
    `network`, and the camera size its data had), runs on `agent_device()`, or on a policy
    server (`model_inputs` here, `forward_batch` there). The camera policy and TCP are two."""

    name: str
    sensors: tuple[str, ...]
    input_size: tuple[int, int]

    def __init__(self, checkpoint: Path | None = None, network: bool = True) -> None:
        if checkpoint is None:
            raise DriveE2EError(
                f"agent {self.name} needs --checkpoint (drivee2e train {self.name} writes one)"
            )
        self.model, self.image_size = self.load(Path(checkpoint), network)
        self.device = agent_device() if network else "cpu"
        self.runner = None
        if self.model is not None:
            self.runner = NetworkRunner(self.model.to(self.device), self.device)

    @staticmethod
    def load(path: Path, network: bool) -> tuple[nn.Module | None, tuple[int, int]]:
        raise NotImplementedError

    def setup(self, route: Route, rig: Rig | None) -> None:
        del route, rig  # the target point in each observation carries the route

    def model_inputs(self, observation: Observation) -> dict[str, np.ndarray]:
        """One observation as the network's inputs: images `(3, 3, H, W)` uint8, vector (6,)."""
        images, vector = observation_inputs(observation, self.image_size, self.input_size)
        return {"images": images[0].numpy(), "vector": vector[0].numpy()}

    def example_inputs(self) -> dict[str, np.ndarray]:
        """Zeros of its inputs' shapes and types (`example_inputs`)."""
        return example_inputs(self.input_size)

    def forward_batch(self, inputs: dict[str, np.ndarray]) -> np.ndarray:
        """Stacked inputs to plans `(B, T, 2)` (metres, ego frame)."""
        if self.runner is None:
            raise DriveE2EError(
                f"this {self.name} agent was built without its network (network=False)"
            )
        return self.runner.plans(inputs["images"], inputs["vector"])

    def act(self, observation: Observation) -> Waypoints:
        inputs = self.model_inputs(observation)
        return Waypoints(self.forward_batch({k: v[None] for k, v in inputs.items()})[0])


class CameraAgent(FrontCameraAgent):
    """The camera policy in closed loop (`FrontCameraAgent`)."""

    name = "camera"
    sensors = FEATURES.cameras
    input_size = FEATURES.image_size
    load = staticmethod(load)


class CameraPlanner:
    """The policy as an open-loop planner of Dataset batches (from `dataset_for`)."""

    name = "camera"

    def __init__(self, checkpoint: Path, device: str = "cpu") -> None:
        model, _ = load(Path(checkpoint))
        self.device = torch.device(device)
        self.model = model.to(self.device)

    @torch.no_grad()
    def plan(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        batch = training.to_device(batch, self.device)
        return self.model(batch["img"], batch_vector(batch)).double().cpu()
