"""The open-loop metrics (`metrics/openloop.py`) as a torchmetrics `Metric`, for training and
validation loops: sums that torchmetrics syncs over processes and devices. Also importable as
`drivee2e_data.metrics.openloop.OpenLoopMetric`."""

from __future__ import annotations

from typing import Any

import torch
from torchmetrics import Metric

from drivee2e_data.metrics import CONVENTIONS
from drivee2e_data.metrics.openloop import ErrorSums, sample_errors


class OpenLoopMetric(Metric):
    """L2 and collision rate accumulated over batches (and, through torchmetrics' sync, over
    processes and devices: every state is a sum).

    `update(plan, truth, mask, size_m=None, rear_axle_to_centre_m=None, agent_boxes=None,
    agent_masks=None)` takes a batch as `DriveE2EDataset` gives it: `gt_ego_fut_trajs`,
    `gt_ego_fut_masks`, `ego_size`, `ego_rear_axle_to_centre`, `gt_agent_fut_boxes` with
    `gt_agent_fut_masks & gt_boxes_mask[..., None]`. Without the agents only L2 is scored.
    """

    full_state_update = False

    def __init__(self, steps: int = 6, convention: str = "stp3", **kwargs: Any) -> None:
        super().__init__(**kwargs)
        if convention not in CONVENTIONS:
            raise ValueError(f"convention {convention!r}: expected one of {', '.join(CONVENTIONS)}")
        self.convention = convention
        for name in ("l2_sum", "l2_count", "collision_sum", "collision_count"):
            self.add_state(
                name, default=torch.zeros(steps, dtype=torch.float64), dist_reduce_fx="sum"
            )

    def update(
        self,
        plan: torch.Tensor,
        truth: torch.Tensor,
        mask: torch.Tensor,
        size_m: torch.Tensor | None = None,
        rear_axle_to_centre_m: torch.Tensor | None = None,
        agent_boxes: torch.Tensor | None = None,
        agent_masks: torch.Tensor | None = None,
    ) -> None:
        errors, valid, hits = sample_errors(
            plan, truth, mask, size_m, rear_axle_to_centre_m, agent_boxes, agent_masks
        )
        self._sums().add(errors, valid, hits)

    def _sums(self) -> ErrorSums:
        """The metric's states as `ErrorSums` (the same tensors: adding to it adds to them)."""
        return ErrorSums(self.l2_sum, self.l2_count, self.collision_sum, self.collision_count)

    def compute(self) -> dict[str, float]:
        return self._sums().summary(self.convention)
