"""The baselines' training loop: masked L1 on the 2 Hz future waypoints, AdamW, a shuffled
order drawn every epoch from the seed (so a resumed run equals an uninterrupted one), and an
atomic checkpoint after every epoch.

Rows come from a `Rows` source: tensors in memory (`TensorRows`, what `extract` reads from the
Dataset: the reference) or a feature cache (`CacheRows`: `loaders/cache.py`, the fast path).
Batches go through a DataLoader: its workers gather the next batches from the cache's memory
maps while the model trains, into pinned memory where the model is on a GPU. Both sources give
the same rows, so a training from either is the same training (tested)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Protocol

import torch
from torch import nn
from torch.utils.data import Dataset

from drivee2e_data.agents import checkpoint as checkpoints
from drivee2e_data.loaders.cache import FeatureCache
from drivee2e_data.loaders.collate import collate
from drivee2e_data.processes import usable_cores

Inputs = Callable[[dict[str, Any]], dict[str, torch.Tensor]]


@dataclass(frozen=True)
class TrainOptions:
    epochs: int = 60
    batch_size: int = 64
    learning_rate: float = 1e-3
    seed: int = 0


def source(
    data: Dataset | FeatureCache,
    inputs: Inputs,
    batch_size: int,
    progress: Callable[[int], None] | None = None,
) -> Rows:
    """Training rows of a feature cache (read as batches are drawn), or of a Dataset (every
    sample read now, `extract`: the reference path)."""
    if isinstance(data, FeatureCache):
        if progress is not None:
            progress(len(data))
        return CacheRows(data, inputs)
    return TensorRows(extract(data, inputs, batch_size, progress))


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


class Rows(Protocol):
    """Training rows: the model's inputs beside `y` (N, T, 2) targets and `mask` (N, T)."""

    def __len__(self) -> int: ...

    def rows(self, indices: torch.Tensor) -> dict[str, torch.Tensor]: ...


@dataclass(frozen=True)
class TensorRows:
    """Rows held in memory as tensors of N rows each."""

    data: dict[str, torch.Tensor]

    def __len__(self) -> int:
        return len(self.data["y"])

    def rows(self, indices: torch.Tensor) -> dict[str, torch.Tensor]:
        return {key: value[indices] for key, value in self.data.items()}


@dataclass(frozen=True)
class CacheRows:
    """Rows of a feature cache: `inputs(batch)` of the cached fields, the targets beside."""

    cache: FeatureCache
    inputs: Inputs

    def __len__(self) -> int:
        return len(self.cache)

    def rows(self, indices: torch.Tensor) -> dict[str, torch.Tensor]:
        batch = self.cache.rows(indices)
        return {
            **self.inputs(batch),
            "y": batch["gt_ego_fut_trajs"].float(),
            "mask": batch["gt_ego_fut_masks"],
        }


def in_memory(source: Rows) -> TensorRows:
    """Every row of `source` in memory (for small features: AD-MLP's)."""
    return TensorRows(source.rows(torch.arange(len(source))))


class _Batches(torch.utils.data.Dataset):
    """A DataLoader's view of a `Rows` source: item k is the batch of rows `indices[k]`."""

    def __init__(self, source: Rows) -> None:
        self.source = source

    def __len__(self) -> int:
        return len(self.source)

    def __getitem__(self, indices: torch.Tensor) -> dict[str, torch.Tensor]:
        return self.source.rows(indices)


class _EpochOrder(torch.utils.data.Sampler):
    """The current epoch's batches of row indices (set before each epoch, read by the loader
    in the main process, so persistent workers follow it)."""

    def __init__(self) -> None:
        self.batches: list[torch.Tensor] = []

    def __iter__(self):  # type: ignore[no-untyped-def]
        return iter(self.batches)

    def __len__(self) -> int:
        return len(self.batches)


def loader_workers(source: Rows) -> int:
    """DataLoader workers for a source: none for rows in memory, else up to 8 of the cores."""
    if isinstance(source, TensorRows):
        return 0
    return min(8, max(usable_cores() - 1, 0))


def to_device(batch: dict[str, Any], device: torch.device | str) -> dict[str, Any]:
    """A batch's tensors on `device` (other values as they are)."""
    return {
        key: value.to(device, non_blocking=True) if isinstance(value, torch.Tensor) else value
        for key, value in batch.items()
    }


# a training's checkpoint (which it resumes from) is written after its last epoch and, before
# that, after the first epoch to end this many seconds after the last write: TCP's, with its
# optimiser's state, is 143 MB (0.16-0.35 s a write on 2 cores), where an epoch of 40 clips at
# 2 Hz takes under 2 s on a GPU: a write every epoch was a tenth of such a training
CHECKPOINT_EVERY_S = 30.0


def fit(
    model: nn.Module,
    data: Rows | dict[str, torch.Tensor],
    predict: Callable[[nn.Module, dict[str, torch.Tensor]], Any],
    checkpoint: Path,
    options: TrainOptions,
    header: dict[str, Any],
    on_epoch: Callable[[int, float], None] | None = None,
    device: str = "cpu",
    mixed_precision: bool = False,
    capture: Callable[[nn.Module, dict[str, torch.Tensor]], None] | None = None,
) -> dict[str, Any]:
    """Train `model` on `data` (a `Rows` source, or tensors of N rows each: `y` (N, T, 2)
    targets and `mask` (N, T) among them), `predict(model, rows)` giving (B, T, 2), or that and
    an auxiliary loss to add; resumes from `checkpoint` when it holds an earlier run of the same
    options. `header` (kind and shapes) goes into the checkpoint. Batches are gathered by a
    DataLoader (workers for a cache) and moved to `device`, where the model lives; with
    `mixed_precision` on a CUDA device the forward pass runs in bfloat16 autocast (casts not
    cached, which CUDA graphs require and a single forward a step does not use). `capture(model,
    rows)`, on a CUDA device, is given the first batch's rows in training mode inside that
    autocast before the first epoch, for the model to record the step as CUDA graphs (TCP's).
    The reported loss is the waypoints' L1 alone."""
    source = TensorRows(data) if isinstance(data, dict) else data
    samples = len(source)
    model.to(device)
    cuda = torch.device(device).type == "cuda"
    # on a GPU one fused kernel updates every parameter (the same AdamW, fewer launches)
    optimiser = torch.optim.AdamW(model.parameters(), lr=options.learning_rate, fused=cuda or None)
    state: dict[str, Any] = {"epoch": 0, "losses": []}
    saved = checkpoints.resume_state(checkpoint, asdict(options), samples, header)
    if saved is not None:
        model.load_state_dict(saved["model"])
        optimiser.load_state_dict(saved["optimiser"])
        state = {"epoch": saved["epoch"], "losses": saved["losses"]}
        if state["epoch"] >= options.epochs:
            return saved
    autocast = torch.autocast(
        "cuda", torch.bfloat16, enabled=cuda and mixed_precision, cache_enabled=False
    )
    if capture is not None and cuda and samples >= options.batch_size:
        # before the loader starts: its pinning thread's allocations would break a capture
        model.train()
        with autocast:
            capture(model, to_device(source.rows(torch.arange(options.batch_size)), device))
    order = _EpochOrder()
    workers = loader_workers(source)
    loader = torch.utils.data.DataLoader(
        _Batches(source),
        sampler=order,
        batch_size=None,
        num_workers=workers,
        pin_memory=cuda,
        persistent_workers=workers > 0,
        prefetch_factor=4 if workers > 0 else None,
        generator=torch.Generator(),  # its seed draw leaves the global generator (dropout) alone
    )
    generator = torch.Generator().manual_seed(options.seed)
    saved_at = time.monotonic()
    for epoch in range(options.epochs):
        permutation = torch.randperm(samples, generator=generator)  # drawn every epoch: resumable
        if epoch < state["epoch"]:
            continue
        order.batches = list(torch.split(permutation, options.batch_size))
        model.train()
        # the epoch's loss summed where it is computed (float64, as Python's floats), read once
        # an epoch: reading it every batch would wait for the GPU every batch
        total, count = torch.zeros((), dtype=torch.float64, device=device), 0
        for rows in loader:
            batch = to_device(rows, device)
            mask = batch["mask"].float()[..., None]
            with autocast:
                predicted = predict(model, batch)
            extra = torch.zeros((), device=device)
            if isinstance(predicted, tuple):
                predicted, extra = predicted
            error = (predicted.float() - batch["y"]).abs() * mask
            loss = error.sum() / mask.sum().clamp_min(1.0) / 2
            optimiser.zero_grad()
            (loss + extra.float()).backward()
            optimiser.step()
            size = len(batch["y"])
            total += loss.detach().double() * size
            count += size
        mean_loss = total.item() / count
        state = {"epoch": epoch + 1, "losses": [*state["losses"], mean_loss]}
        if epoch + 1 == options.epochs or time.monotonic() - saved_at >= CHECKPOINT_EVERY_S:
            weights = {key: value.cpu() for key, value in model.state_dict().items()}
            document = {**header, "model": weights, "optimiser": optimiser.state_dict()}
            checkpoints.save(
                checkpoint, {**document, "options": asdict(options), "samples": samples, **state}
            )
            saved_at = time.monotonic()
        if on_epoch is not None:
            on_epoch(epoch + 1, mean_loss)
    return torch.load(checkpoint, map_location="cpu", weights_only=True)
