"""Batching samples: fixed-shape tensors are stacked, per-box and per-map-polyline fields
padded to the batch's most rows (with `gt_boxes_mask`, `gt_map_mask`), point clouds and strings
kept as lists, JPEG bytes kept for `decode_jpegs` (on the GPU, in the main process).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch

from drivee2e_data.loaders.dataset import BOX_FIELDS, MAP_FIELDS, scalar_tensor
from drivee2e_data.loaders.images import decode_batch

LIST_FIELDS = ("points", "radar_points", "img_jpeg")
# (field whose length counts the rows, the fields padded to the batch's most rows, their mask)
PADDED = (
    ("gt_labels", BOX_FIELDS, "gt_boxes_mask"),
    ("gt_map_labels", MAP_FIELDS, "gt_map_mask"),
)


def collate(samples: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """A batch from samples of `DriveE2EDataset`."""
    if not samples:
        raise ValueError("collate needs at least one sample")
    batch: dict[str, Any] = {}
    rows: dict[str, int] = {}  # padded field -> rows it is padded to
    for count_key, fields, mask_key in PADDED:
        if count_key not in samples[0]:
            continue
        most = max(len(s[count_key]) for s in samples)
        batch[mask_key] = torch.zeros((len(samples), most), dtype=torch.bool)
        for k, s in enumerate(samples):
            batch[mask_key][k, : len(s[count_key])] = True
        rows.update(dict.fromkeys(fields, most))
    for key in samples[0]:
        values = [s[key] for s in samples]
        if key in rows and torch.is_tensor(values[0]):
            batch[key] = _pad(values, rows[key])
        elif key in LIST_FIELDS or not (
            torch.is_tensor(values[0]) or isinstance(values[0], (int, float))
        ):
            batch[key] = values
        elif torch.is_tensor(values[0]):
            batch[key] = torch.stack(values)
        else:
            batch[key] = scalar_tensor(values)
    return batch


def _pad(values: list[torch.Tensor], rows: int) -> torch.Tensor:
    first = values[0]
    padded = torch.zeros((len(values), rows, *first.shape[1:]), dtype=first.dtype)
    for k, value in enumerate(values):
        padded[k, : len(value)] = value
    return padded


def decode_jpegs(
    batch: dict[str, Any],
    full_size: tuple[int, int],
    image_size: tuple[int, int] | None = None,
    device: str | torch.device = "cuda",
) -> dict[str, Any]:
    """Replace a `decode="none"` batch's `img_jpeg` by `img` `(B, N, 3, H, W)` (or
    `(B, Q, N, 3, H, W)` with a queue) decoded on `device`, all images in one call."""
    jpegs = batch.pop("img_jpeg")
    nested = isinstance(jpegs[0][0], list)  # a queue: per sample, per frame, per camera
    flat = [j for sample in jpegs for frame in (sample if nested else [sample]) for j in frame]
    images = decode_batch(flat, full_size, image_size, device)
    shape = (len(jpegs), len(jpegs[0]), len(jpegs[0][0])) if nested else (len(jpegs), len(jpegs[0]))
    batch["img"] = images.reshape(*shape, *images.shape[1:])
    return batch
