"""AD-MLP (after Zhai et al., "Rethinking the Open-Loop Evaluation of End-to-End Autonomous
Driving in nuScenes"): an MLP from the ego's own state alone (its 2 Hz history, IMU, velocity,
steering and the high-level command) to the planned waypoints. No camera, no map, no agents:
the baseline that shows how much of open-loop L2 the ego's own motion explains.

Training is resumable: the checkpoint is written atomically after every epoch with the
optimiser state, and a rerun with the same output continues from the last finished epoch (a
larger `epochs` continues training; the result equals one uninterrupted run).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from torch import nn

from drivee2e_data.agents import checkpoint as checkpoints
from drivee2e_data.agents import training
from drivee2e_data.agents.training import TrainOptions, fit
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.evaluate.agent import Observation, Waypoints
from drivee2e_data.loaders.cache import FeatureCache, FeatureSpec
from drivee2e_data.loaders.dataset import DriveE2EDataset

HIDDEN = 512
MIN_SCALE = 0.1


def features(batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """(B, F) the ego's history (positions and mask), status and command, as float32."""
    history = batch["gt_ego_his_trajs"].float()
    history_mask = batch["gt_ego_his_masks"].float()
    return torch.cat(
        [
            history.flatten(1),
            history_mask,
            batch["ego_status"].float(),
            batch["gt_ego_fut_cmd"].float(),
        ],
        dim=1,
    )


def continuous_features(history_steps: int) -> torch.Tensor:
    """Indices into `features` of the continuous values (history positions, ego status)."""
    history = torch.arange(2 * history_steps)
    status = 3 * history_steps + torch.arange(10)  # after the positions and their mask
    return torch.cat([history, status])


class ADMLP(nn.Module):
    """Standardised features -> two hidden layers -> `steps` waypoints."""

    name = "admlp"

    def __init__(self, inputs: int, steps: int = 6) -> None:
        super().__init__()
        self.steps = steps
        self.register_buffer("mean", torch.zeros(inputs))
        self.register_buffer("scale", torch.ones(inputs))
        self.layers = nn.Sequential(
            nn.Linear(inputs, HIDDEN),
            nn.ReLU(),
            nn.Linear(HIDDEN, HIDDEN),
            nn.ReLU(),
            nn.Linear(HIDDEN, steps * 2),
        )

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        return self.layers((inputs - self.mean) / self.scale).reshape(-1, self.steps, 2)

    @torch.no_grad()
    def plan(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        self.eval()
        return self(features(batch)).double()


FEATURES = FeatureSpec("ego")  # the ego's state, command and 2 Hz history: no image


def inputs(batch: dict[str, Any]) -> dict[str, torch.Tensor]:
    return {"x": features(batch)}


def extract(
    dataset: DriveE2EDataset, progress: Callable[[int], None] | None = None
) -> dict[str, torch.Tensor]:
    """Features `x`, targets `y` and masks of every sample, in dataset order."""
    return training.extract(dataset, inputs, 256, progress)


def train(
    dataset: DriveE2EDataset | FeatureCache,
    checkpoint: Path,
    options: TrainOptions | None = None,
    on_epoch: Callable[[int, float], None] | None = None,
    on_sample: Callable[[int], None] | None = None,
    device: str = "cpu",
) -> dict[str, Any]:
    """Train on every sample of `dataset` (a Dataset built with `cameras=()`, or the split's
    feature cache of `FEATURES`); returns the checkpoint."""
    options = options or TrainOptions()
    if len(dataset) == 0:
        raise DriveE2EError(
            f"{dataset.manifest}: split {dataset.split!r} has no samples to train on"
        )
    rows = training.in_memory(training.source(dataset, inputs, 256, on_sample))
    data = rows.data
    torch.manual_seed(options.seed)
    model = ADMLP(data["x"].shape[1], data["y"].shape[1])
    # continuous features are standardised; a spread under 0.1 (m, m/s, rad/s) counts as 0.1,
    # so a feature constant in training (no yaw rate on straight clips) is not blown up 1000-fold
    # where it varies at test time. Masks and the one-hot command stay 0/1 as they are.
    # per history step two positions and a mask, then the status (10) and the command (3)
    continuous = continuous_features((data["x"].shape[1] - 13) // 3)
    model.mean[continuous] = data["x"][:, continuous].mean(0)
    model.scale[continuous] = data["x"][:, continuous].std(0).clamp_min(MIN_SCALE)
    header = {"kind": ADMLP.name, "inputs": model.mean.shape[0], "steps": model.steps}
    return fit(
        model, rows, lambda m, rows: m(rows["x"]), checkpoint, options, header, on_epoch, device
    )


def load_checkpoint(path: Path) -> dict[str, Any]:
    return checkpoints.load(path, ADMLP.name, "drivee2e train admlp")


def load(path: Path) -> ADMLP:
    saved = load_checkpoint(path)
    model = ADMLP(saved["inputs"], saved["steps"])
    model.load_state_dict(saved["model"])
    return model


class ADMLPAgent:
    """AD-MLP in closed loop: the observation's ego history, status and command through a
    trained checkpoint to waypoints. No sensors are rendered for it."""

    name = "admlp"
    sensors: tuple[str, ...] = ()
    image_size = None

    def __init__(self, checkpoint: Path | None = None) -> None:
        if checkpoint is None:
            raise DriveE2EError("agent admlp needs --checkpoint (drivee2e train admlp writes one)")
        self.model = load(Path(checkpoint))
        history_steps = (int(self.model.mean.shape[0]) - 13) // 3
        if history_steps != 4:
            raise DriveE2EError(
                f"{checkpoint}: trained with {history_steps} history steps; closed loop serves 4 "
                "(2 s at 2 Hz, the Dataset's default)"
            )

    def setup(self, route: object, rig: object) -> None:
        del route, rig  # AD-MLP sees only the ego's own state

    def act(self, observation: Observation) -> Waypoints:
        command = torch.zeros(1, 3)
        command[0, int(observation.command) - 1] = 1.0
        batch = {
            "gt_ego_his_trajs": torch.as_tensor(observation.history_xy_m, dtype=torch.float32)[
                None
            ],
            "gt_ego_his_masks": torch.as_tensor(observation.history_mask)[None],
            "ego_status": torch.as_tensor(observation.ego_status, dtype=torch.float32)[None],
            "gt_ego_fut_cmd": command,
        }
        return Waypoints(self.model.plan(batch)[0].numpy())
