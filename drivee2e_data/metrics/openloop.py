"""Open-loop planning metrics (SPEC.md): L2 of the planned ego waypoints against the logged
future, and the collision rate of the planned ego box against the logged agents' boxes.

Plans are `(B, T, 2)` ego-frame waypoints (x forward, y left, rear axle) at 2 Hz, step k at
(k + 1) * 0.5 s. Steps the log does not have (clip end) are masked out of every mean, never
padded. Two conventions for L2 (and collision) at horizon h, both offered by name:

- `stp3` (ST-P3, VAD): the mean over the steps up to h of the per-step means;
- `uniad` (UniAD): the per-step mean at the step of h itself.

Per-step means are taken over all samples that have that step, so the accumulated state is
sums and counts per step, which add across batches, processes and devices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

from drivee2e_data.geometry import box_corners_2d
from drivee2e_data.geometry import boxes_overlap as geometry_overlap
from drivee2e_data.metrics import CONVENTIONS, STEP_S

HORIZONS_S = (1.0, 2.0, 3.0)


def l2_per_step(plan: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """(B, T) Euclidean distance between planned and logged waypoints `(B, T, 2)`."""
    return torch.linalg.vector_norm(plan.double() - truth.double(), dim=-1)


def plan_boxes(
    plan: torch.Tensor, size_m: torch.Tensor, rear_axle_to_centre_m: torch.Tensor
) -> torch.Tensor:
    """(B, T, 5) ego boxes x, y (centre), length, width, yaw along a plan `(B, T, 2)` of
    rear-axle waypoints. Heading: the direction from the previous waypoint (the origin for the
    first); kept from the step before where the plan barely moves."""
    plan = plan.double()
    previous = torch.cat([torch.zeros_like(plan[:, :1]), plan[:, :-1]], dim=1)
    delta = plan - previous
    yaw = torch.atan2(delta[..., 1], delta[..., 0])
    still = torch.linalg.vector_norm(delta, dim=-1) < 0.05
    for step in range(plan.shape[1]):  # a standing plan keeps the heading it had
        before = yaw[:, step - 1] if step else torch.zeros_like(yaw[:, 0])
        yaw[:, step] = torch.where(still[:, step], before, yaw[:, step])
    offset = rear_axle_to_centre_m.double().reshape(-1, 1)
    centre = plan + offset[..., None] * torch.stack([torch.cos(yaw), torch.sin(yaw)], dim=-1)
    size = size_m.double().reshape(-1, 1, size_m.shape[-1])[..., :2].expand(-1, plan.shape[1], 2)
    return torch.cat([centre, size, yaw[..., None]], dim=-1)


def boxes_overlap(first: torch.Tensor, second: torch.Tensor) -> torch.Tensor:
    """Whether rotated rectangles (..., 5) x, y, length, width, yaw overlap (separating axes,
    `geometry.boxes_overlap`; touching counts as apart)."""
    a, b = first.double().cpu().numpy(), second.double().cpu().numpy()
    corners_a = box_corners_2d(a[..., :2], a[..., 4], a[..., 2], a[..., 3])
    corners_b = box_corners_2d(b[..., :2], b[..., 4], b[..., 2], b[..., 3])
    return torch.from_numpy(geometry_overlap(corners_a, corners_b))


def collisions(
    plan: torch.Tensor,
    size_m: torch.Tensor,
    rear_axle_to_centre_m: torch.Tensor,
    agent_boxes: torch.Tensor,
    agent_masks: torch.Tensor,
) -> torch.Tensor:
    """(B, T) whether the planned ego box at each step overlaps any logged agent box at the same
    step: `agent_boxes (B, M, T, 5)` in the current ego frame, `agent_masks (B, M, T)`."""
    ego = plan_boxes(plan, size_m, rear_axle_to_centre_m)  # (B, T, 5)
    if agent_boxes.shape[1] == 0:
        return torch.zeros(plan.shape[:2], dtype=torch.bool)
    hits = boxes_overlap(ego[:, None], agent_boxes)
    return (hits & agent_masks.bool()).any(dim=1)


def sample_errors(
    plan: torch.Tensor,
    truth: torch.Tensor,
    mask: torch.Tensor,
    size_m: torch.Tensor | None = None,
    rear_axle_to_centre_m: torch.Tensor | None = None,
    agent_boxes: torch.Tensor | None = None,
    agent_masks: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Each sample's L2 per step `(B, T)` float64, the steps the log has `(B, T)` bool, and
    whether the planned box hits an agent at each step `(B, T)` bool (None without the
    agents): what `OpenLoopMetric` sums, row by row, so any subset of rows scores as if it had
    been a batch of its own. Arguments as `OpenLoopMetric.update` takes them."""
    if plan.shape != truth.shape or plan.shape[:2] != mask.shape:
        raise ValueError(
            f"plan {tuple(plan.shape)}, truth {tuple(truth.shape)} and mask "
            f"{tuple(mask.shape)}: expected (B, T, 2), (B, T, 2) and (B, T)"
        )
    valid = mask.bool()
    errors = l2_per_step(plan, truth)
    if agent_boxes is None or agent_masks is None:
        return errors, valid, None
    if size_m is None or rear_axle_to_centre_m is None:
        raise ValueError("collisions need the ego's size and rear-axle offset")
    hits = collisions(
        plan.cpu(), size_m.cpu(), rear_axle_to_centre_m.cpu(), agent_boxes.cpu(), agent_masks.cpu()
    )
    return errors, valid, hits.to(valid.device)


def summarize(
    sums: torch.Tensor, counts: torch.Tensor, convention: str, prefix: str
) -> dict[str, float]:
    """Values at 1 s, 2 s, 3 s, their mean (`avg`) and the paper's mean of 1 s and 2 s
    (`avg_1_2s`), from per-step sums and counts."""
    if convention not in CONVENTIONS:
        raise ValueError(f"convention {convention!r}: expected one of {', '.join(CONVENTIONS)}")
    steps = sums.shape[0]
    per_step = [float(sums[k] / counts[k]) if counts[k] > 0 else math.nan for k in range(steps)]
    result: dict[str, float] = {}
    for horizon in HORIZONS_S:
        last = round(horizon / STEP_S) - 1
        if last >= steps:
            continue
        if convention == "uniad":
            value = per_step[last]
        else:
            seen = [v for v in per_step[: last + 1] if not math.isnan(v)]
            value = sum(seen) / len(seen) if seen else math.nan
        result[f"{prefix}_{horizon:g}s"] = value
    at = [result[f"{prefix}_{h:g}s"] for h in HORIZONS_S if f"{prefix}_{h:g}s" in result]
    result[f"{prefix}_avg"] = sum(at) / len(at) if at else math.nan
    result[f"{prefix}_avg_1_2s"] = sum(at[:2]) / len(at[:2]) if at else math.nan
    return result


@dataclass
class ErrorSums:
    """Per-step sums and counts of samples' `sample_errors` (float64 `(T,)` each): what the
    metrics of every convention are computed from. Rows add in any grouping."""

    l2_sum: torch.Tensor
    l2_count: torch.Tensor
    collision_sum: torch.Tensor
    collision_count: torch.Tensor

    @classmethod
    def zeros(cls, steps: int) -> ErrorSums:
        return cls(*(torch.zeros(steps, dtype=torch.float64) for _ in range(4)))

    def add(self, errors: torch.Tensor, valid: torch.Tensor, hits: torch.Tensor | None) -> None:
        """Accumulate rows of `sample_errors`."""
        self.l2_sum += torch.where(valid, errors, 0.0).sum(0).to(self.l2_sum)
        self.l2_count += valid.sum(0).to(self.l2_count)
        if hits is not None:
            self.collision_sum += (hits & valid).sum(0).to(self.collision_sum)
            self.collision_count += valid.sum(0).to(self.collision_count)

    def summary(self, convention: str) -> dict[str, float]:
        """L2 (and the collision rate where agents were scored) in `convention`."""
        result = summarize(self.l2_sum, self.l2_count, convention, "l2")
        if float(self.collision_count.sum()) > 0:
            result.update(
                summarize(self.collision_sum, self.collision_count, convention, "collision")
            )
        return result


def __getattr__(name: str) -> Any:
    # `OpenLoopMetric` is a torchmetrics Metric, and importing torchmetrics (with the scipy it
    # loads) took 3.8 s of the 6.5 s of `drivee2e openloop` on 2 cores: scoring files needs only
    # `ErrorSums`, so the Metric is defined on first use (`metrics/openloop_metric.py`)
    if name == "OpenLoopMetric":
        from drivee2e_data.metrics.openloop_metric import OpenLoopMetric

        return OpenLoopMetric
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
