"""The baselines' training loop: masked L1 on the 2 Hz future waypoints, AdamW, a shuffled
order drawn every epoch from the seed (so a resumed run equals an uninterrupted one), and an
atomic checkpoint after every epoch."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
from torch import nn
from torch.utils.data import Dataset

from drivee2e_data.agents import checkpoint as checkpoints
from drivee2e_data.loaders.collate import collate


@dataclass(frozen=True)
class TrainOptions:
    epochs: int = 60
    batch_size: int = 64
    learning_rate: float = 1e-3
    seed: int = 0


def extract(
    dataset: Dataset,
    inputs: Callable[[dict[str, Any]], dict[str, torch.Tensor]],
    batch_size: int,
    progress: Callable[[int], None] | None = None,
) -> dict[str, torch.Tensor]:
    """Every sample of `dataset` in order, collated `batch_size` at a time: the model's
    `inputs(batch)` beside the targets `y` (the 2 Hz future) and their `mask`."""
    rows: dict[str, list[torch.Tensor]] = {}
    for start in range(0, len(dataset), batch_size):
        batch = collate([dataset[i] for i in range(start, min(start + batch_size, len(dataset)))])
        columns = {
            **inputs(batch),
            "y": batch["gt_ego_fut_trajs"].float(),
            "mask": batch["gt_ego_fut_masks"],
        }
        for key, value in columns.items():
            rows.setdefault(key, []).append(value)
        if progress is not None:
            progress(len(batch["gt_ego_fut_trajs"]))
    return {key: torch.cat(value) for key, value in rows.items()}


def fit(
    model: nn.Module,
    data: dict[str, torch.Tensor],
    predict: Callable[[nn.Module, dict[str, torch.Tensor]], Any],
    checkpoint: Path,
    options: TrainOptions,
    header: dict[str, Any],
    on_epoch: Callable[[int, float], None] | None = None,
    device: str = "cpu",
) -> dict[str, Any]:
    """Train `model` on `data` (rows of tensors; `y` (N, T, 2) targets and `mask` (N, T) among
    them), `predict(model, rows)` giving (B, T, 2), or that and an auxiliary loss to add;
    resumes from `checkpoint` when it holds an earlier run of the same options. `header` (kind
    and shapes) goes into the checkpoint. The data stays where it is (the CPU); each batch goes
    to `device`, the model lives there. The reported loss is the waypoints' L1 alone."""
    samples = len(data["y"])
    model.to(device)
    optimiser = torch.optim.AdamW(model.parameters(), lr=options.learning_rate)
    state: dict[str, Any] = {"epoch": 0, "losses": []}
    saved = checkpoints.resume_state(checkpoint, asdict(options), samples)
    if saved is not None:
        model.load_state_dict(saved["model"])
        optimiser.load_state_dict(saved["optimiser"])
        state = {"epoch": saved["epoch"], "losses": saved["losses"]}
        if state["epoch"] >= options.epochs:
            return saved
    generator = torch.Generator().manual_seed(options.seed)
    for epoch in range(options.epochs):
        order = torch.randperm(samples, generator=generator)  # drawn every epoch: resumable
        if epoch < state["epoch"]:
            continue
        model.train()
        total, count = 0.0, 0
        for start in range(0, samples, options.batch_size):
            rows = order[start : start + options.batch_size]
            batch = {key: value[rows].to(device) for key, value in data.items()}
            mask = batch["mask"].float()[..., None]
            predicted = predict(model, batch)
            extra = torch.zeros((), device=device)
            if isinstance(predicted, tuple):
                predicted, extra = predicted
            error = (predicted - batch["y"]).abs() * mask
            loss = error.sum() / mask.sum().clamp_min(1.0) / 2
            optimiser.zero_grad()
            (loss + extra).backward()
            optimiser.step()
            total, count = total + loss.item() * len(rows), count + len(rows)
        state = {"epoch": epoch + 1, "losses": [*state["losses"], total / count]}
        weights = {key: value.cpu() for key, value in model.state_dict().items()}
        document = {**header, "model": weights, "optimiser": optimiser.state_dict()}
        checkpoints.save(
            checkpoint, {**document, "options": asdict(options), "samples": samples, **state}
        )
        if on_epoch is not None:
            on_epoch(epoch + 1, total / count)
    return torch.load(checkpoint, map_location="cpu", weights_only=True)
