"""The constant-velocity baseline: the ego keeps its current velocity (no training)."""

from __future__ import annotations

import numpy as np
import torch

from drivee2e_data.evaluate.agent import Observation, Waypoints
from drivee2e_data.metrics import STEP_S


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


class ConstantVelocityAgent:
    """Constant velocity in closed loop: keeps its current speed straight ahead (waypoints along
    the ego's x axis), so it holds a lane until the road turns and never stops."""

    name = "constant-velocity"
    sensors: tuple[str, ...] = ()
    image_size = None

    def __init__(self, checkpoint: object = None, steps: int = 6) -> None:
        del checkpoint  # nothing to load
        self.steps = steps

    def setup(self, route: object, rig: object) -> None:
        del route, rig

    def act(self, observation: Observation) -> Waypoints:
        times = STEP_S * np.arange(1, self.steps + 1)
        return Waypoints(np.column_stack([observation.speed_mps * times, np.zeros(self.steps)]))
