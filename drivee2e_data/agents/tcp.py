"""A TCP/TransFuser-class camera baseline (after Wu et al., "Trajectory-guided Control
Prediction for End-to-end Autonomous Driving", NeurIPS 2022, its trajectory branch): the three
front cameras through a shared ResNet trunk (`agents/resnet.py`, ResNet-18's shape, randomly
initialised), the ego's speed, the route's command and target point through a measurement
encoder, and a GRU that rolls out the 2 Hz waypoints towards the target point; a speed head
reads the image features alone (TCP's auxiliary: the speed must be seen, not only copied from
the input). Trained with `drivee2e train tcp DATA [--device cuda]`.

Images go through the Dataset's decoder, in training and in closed loop alike, as for the small
camera policy (`agents/camera.py`), at `INPUT_SIZE`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from torch import nn

from drivee2e_data.agents import camera, training
from drivee2e_data.agents import checkpoint as checkpoints
from drivee2e_data.agents.camera import FRONT_CAMERAS, PIXEL_MEAN, PIXEL_STD
from drivee2e_data.agents.resnet import RESNET18_BLOCKS, RESNET18_WIDTH, ResNet
from drivee2e_data.agents.training import TrainOptions, fit
from drivee2e_data.loaders.cache import EGO_FIELDS, FeatureCache, FeatureSpec
from drivee2e_data.loaders.dataset import DriveE2EDataset

# 256 x 144 per camera: TCP's front view is 900 x 256 over a wider field; three of ours side by
# side are 768 x 144, a 1/6.25 scale of the 1600 x 900 cameras (a JPEG read at 1/4 in the DCT,
# then area-resized)
INPUT_SIZE = (256, 144)
# what the policy reads, declared once: its training cache and its closed-loop cameras
FEATURES = FeatureSpec("tcp", EGO_FIELDS, FRONT_CAMERAS, INPUT_SIZE)
SPEED_LOSS_WEIGHT = 0.05  # TCP's weight of the speed head's L1 beside the waypoints'
GRU_HIDDEN = 256
TARGET_SCALE_M = 20.0  # the GRU's target-point input, as the measurement vector scales it


class TCPPolicy(nn.Module):
    """Images `(B, K, 3, H, W)` uint8 and the measurement vector `(B, 6)` (command one-hot,
    speed / 10 m/s, target point / 20 m: `camera.vector_features`) to `steps` waypoints
    `(B, T, 2)` in metres (ego frame) and the speed the images show `(B,)` in m/s."""

    name = "tcp"

    def __init__(
        self,
        cameras: int = 3,
        steps: int = 6,
        width: int = RESNET18_WIDTH,
        blocks: tuple[int, ...] = RESNET18_BLOCKS,
    ) -> None:
        super().__init__()
        self.steps, self.width, self.blocks = steps, width, tuple(blocks)
        self.trunk = ResNet(self.blocks, width)  # shared by the cameras
        features = self.trunk.features
        self.image = nn.Sequential(nn.Linear(cameras * features, 256), nn.ReLU())
        self.measurements = nn.Sequential(
            nn.Linear(6, 128), nn.ReLU(), nn.Linear(128, 128), nn.ReLU()
        )
        self.join = nn.Sequential(nn.Linear(256 + 128, GRU_HIDDEN), nn.ReLU())
        # each step's input: the last waypoint and the target point relative to it (TCP's)
        self.decoder = nn.GRUCell(4, GRU_HIDDEN)
        self.step_out = nn.Linear(GRU_HIDDEN, 2)
        self.speed = nn.Sequential(nn.Linear(256, 64), nn.ReLU(), nn.Linear(64, 1))
        self.register_buffer("augment_step", torch.zeros((), dtype=torch.int64))
        self.register_load_state_dict_post_hook(camera.forget_host_counter)
        # CUDA graphs of the training step's `plan`, by input shape (`capture`); a plain dict,
        # so neither the state dict nor `modules()` sees them
        self._graphs: dict[tuple[int, ...], Callable[..., tuple[torch.Tensor, torch.Tensor]]] = {}

    def forward(
        self, images: torch.Tensor, vector: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        normalised = self.normalise(images)
        graphed = self._graphs.get(tuple(normalised.shape)) if self.training else None
        if graphed is not None:
            return graphed(normalised, vector)
        return self.plan(normalised, vector)

    def normalise(self, images: torch.Tensor, augment: bool = True) -> torch.Tensor:
        """`(B, K, 3, H, W)` uint8 to the trunk's input `(B * K, 3, H, W)`: scaled to [0, 1],
        in training (with `augment`) each image times a brightness gain, normalised; in
        channels-last memory on a GPU (the convolutions' fast layout there)."""
        batch, cameras = images.shape[:2]
        pixels = images.flatten(0, 1).float() / 255.0
        if self.training and augment:
            gain = camera.brightness_gains(self, batch * cameras, pixels.device)
            pixels = (pixels * gain.view(-1, 1, 1, 1)).clamp(0.0, 1.0)
        normalised = (pixels - PIXEL_MEAN) / PIXEL_STD
        if normalised.is_cuda:
            normalised = normalised.contiguous(memory_format=torch.channels_last)
        return normalised

    def plan(
        self, normalised: torch.Tensor, vector: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The trunk's input (`normalise`) and the measurement vector to waypoints and speed."""
        batch = len(vector)
        features = self.trunk(normalised).view(batch, -1)
        seen = self.image(features)
        hidden = self.join(torch.cat([seen, self.measurements(vector)], 1))
        target_m = vector[:, 4:6] * TARGET_SCALE_M
        point = torch.zeros(batch, 2, device=vector.device, dtype=hidden.dtype)
        waypoints = []
        for _ in range(self.steps):
            step_input = torch.cat([point, target_m - point], 1) / TARGET_SCALE_M
            hidden = self.decoder(step_input, hidden)
            point = point + self.step_out(hidden)
            waypoints.append(point)
        return torch.stack(waypoints, 1), self.speed(seen).squeeze(1)

    def capture(self, images: torch.Tensor, vector: torch.Tensor) -> None:
        """Record `plan`'s training forward and backward for inputs shaped like these as CUDA
        graphs (call it in training mode, on the GPU, inside the training's autocast, which
        must not cache casts); `forward` then replays them for batches of that shape, and runs
        `plan` eagerly for any other (an epoch's last, shorter batch). A step then launches a
        graph instead of several hundred kernels from Python, which bound the training at about
        16 ms a step whatever its size (docs/benchmarks.md). The capture's warm-up passes
        update the batch norms' running statistics: every buffer is put back afterwards, so the
        training is the one it would have been without graphs, to the GPU's arithmetic."""
        normalised = self.normalise(images, augment=False)
        buffers = {name: value.clone() for name, value in self.named_buffers()}
        graphed = torch.cuda.make_graphed_callables(_Plan(self), (normalised, vector))
        with torch.no_grad():
            for name, value in self.named_buffers():
                value.copy_(buffers[name])
        self._graphs[tuple(normalised.shape)] = graphed


class _Plan(nn.Module):
    """A policy's `plan` as a module of its own (what `make_graphed_callables` records: its
    parameters are the policy's)."""

    def __init__(self, policy: TCPPolicy) -> None:
        super().__init__()
        self.policy = policy

    def forward(
        self, normalised: torch.Tensor, vector: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        return self.policy.plan(normalised, vector)


def dataset_for(root: Path, split: str, split_name: str = "default") -> DriveE2EDataset:
    """The split's samples as the policy reads them (front cameras at `INPUT_SIZE`)."""
    return camera.dataset_for(root, split, split_name, INPUT_SIZE)


def inputs(batch: dict[str, Any]) -> dict[str, torch.Tensor]:
    """The policy's inputs of a batch: images, measurement vector, and the speed (its target)."""
    speed = batch["ego_status"][:, 6].float()
    return {"images": batch["img"], "vector": camera.batch_vector(batch), "speed": speed}


def extract(
    dataset: DriveE2EDataset, progress: Callable[[int], None] | None = None
) -> dict[str, torch.Tensor]:
    """Images, measurement vectors, speeds, targets `y` and masks of every sample, in order."""
    return training.extract(dataset, inputs, 32, progress)


def _predict(model: nn.Module, rows: dict[str, torch.Tensor]):  # type: ignore[no-untyped-def]
    """The waypoints and the speed head's L1 loss, weighted (`training.fit`'s contract)."""
    waypoints, speed = model(rows["images"], rows["vector"])
    return waypoints, SPEED_LOSS_WEIGHT * (speed - rows["speed"]).abs().mean()


def train(
    dataset: DriveE2EDataset | FeatureCache,
    checkpoint: Path,
    options: TrainOptions | None = None,
    on_epoch: Callable[[int, float], None] | None = None,
    on_sample: Callable[[int], None] | None = None,
    device: str = "cpu",
    width: int = RESNET18_WIDTH,
    cuda_graphs: bool = True,
) -> dict[str, Any]:
    """Train on every sample of `dataset` (from `dataset_for`, or the split's feature cache of
    `FEATURES`) on `device`; returns the checkpoint. `width`: the trunk's first stage's
    channels (64: ResNet-18). On a GPU the forward pass runs in bfloat16 autocast, the trunk in
    channels-last memory, and with `cuda_graphs` each full batch's forward and backward as CUDA
    graphs (`TCPPolicy.capture`)."""
    options = options or TrainOptions(epochs=30, batch_size=32, learning_rate=3e-4)
    full_size = camera.trainable_size(dataset, INPUT_SIZE, TCPPolicy.name)
    data = training.source(dataset, inputs, 32, on_sample)
    torch.manual_seed(options.seed)
    model = TCPPolicy(len(FRONT_CAMERAS), int(data.rows(torch.arange(1))["y"].shape[1]), width)
    header = {"kind": TCPPolicy.name, "steps": model.steps, "width": width,
              "blocks": list(model.blocks), "camera_size": full_size}  # fmt: skip
    gpu = torch.device(device).type == "cuda"
    if gpu:
        model.trunk.to(memory_format=torch.channels_last)
    return fit(
        model, data, _predict, checkpoint, options, header, on_epoch, device,
        mixed_precision=gpu, capture=_capture if gpu and cuda_graphs else None,
    )  # fmt: skip


def _capture(model: nn.Module, rows: dict[str, torch.Tensor]) -> None:
    """`training.fit`'s capture: the policy's graphs for batches shaped like `rows`."""
    model.capture(rows["images"], rows["vector"])


def load(path: Path, network: bool = True) -> tuple[TCPPolicy | None, tuple[int, int]]:
    """The trained policy (on the CPU; None without `network`) and the camera image size its
    data was collected at."""
    saved = checkpoints.load(path, TCPPolicy.name, "drivee2e train tcp")
    width, height = saved["camera_size"]
    if not network:
        return None, (int(width), int(height))
    model = TCPPolicy(len(FRONT_CAMERAS), saved["steps"], saved["width"], tuple(saved["blocks"]))
    model.load_state_dict(saved["model"])
    model.eval()
    return model, (int(width), int(height))


class TCPAgent(camera.FrontCameraAgent):
    """The TCP-class policy in closed loop (`camera.FrontCameraAgent`)."""

    name = "tcp"
    sensors = FEATURES.cameras
    input_size = FEATURES.image_size
    load = staticmethod(load)


class TCPPlanner:
    """The policy as an open-loop planner of Dataset batches (from `dataset_for`)."""

    name = "tcp"

    def __init__(self, checkpoint: Path, device: str = "cpu") -> None:
        model, _ = load(Path(checkpoint))
        self.device = torch.device(device)
        self.model = model.to(self.device)

    @torch.no_grad()
    def plan(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        batch = training.to_device(batch, self.device)
        plan, _ = self.model(batch["img"], camera.batch_vector(batch))
        return plan.double().cpu()
