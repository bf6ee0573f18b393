"""The constant-velocity baseline: the ego keeps its current velocity (no training)."""

from __future__ import annotations

import torch

from drivee2e_data.metrics.openloop import STEP_S


class ConstantVelocity:
    """Plans `(B, T, 2)` ego-frame waypoints at 2 Hz from a batch's `ego_status` (velocity at
    indices 6, 7)."""

    name = "constant-velocity"

    def __init__(self, steps: int = 6) -> None:
        self.steps = steps

    def plan(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        velocity = batch["ego_status"][:, 6:8].double()
        times = STEP_S * torch.arange(1, self.steps + 1, dtype=torch.float64)
        return velocity[:, None, :] * times[None, :, None]
