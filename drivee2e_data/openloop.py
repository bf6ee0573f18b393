"""Open-loop evaluation on a data root: write a planner's predictions for a split, and score a
predictions file against the logs, overall and per behaviour category.

The predictions file is Parquet with one row per scored frame:

| column | type | meaning |
|---|---|---|
| `scenario_id` | string | the clip |
| `frame` | int | the frame (as in `logs/index.parquet`) |
| `plan_x_m` | list of 6 float | planned rear-axle x at 0.5, 1.0, ..., 3.0 s, ego frame of `frame` (forward) |
| `plan_y_m` | list of 6 float | the same, y (left) |
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, Protocol

import pyarrow as pa
import pyarrow.parquet as pq
import torch

from drivee2e_data import store
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.loaders.cache import FeatureCache
from drivee2e_data.loaders.collate import collate
from drivee2e_data.loaders.dataset import DriveE2EDataset
from drivee2e_data.metrics import CONVENTIONS

PREDICTION_SCHEMA = pa.schema(
    [
        ("scenario_id", pa.string()),
        ("frame", pa.int32()),
        ("plan_x_m", pa.list_(pa.float64())),
        ("plan_y_m", pa.list_(pa.float64())),
    ]
)
BATCH = 128


class Planner(Protocol):
    name: str

    def plan(self, batch: dict[str, Any]) -> torch.Tensor: ...


def _batches(
    dataset: DriveE2EDataset | FeatureCache, indices: list[int]
) -> Iterable[tuple[list[int], dict[str, Any]]]:
    """Batches of these samples: gathered from a feature cache, or collated from a Dataset."""
    for start in range(0, len(indices), BATCH):
        chunk = indices[start : start + BATCH]
        if isinstance(dataset, FeatureCache):
            yield chunk, dataset.rows(chunk)
        else:
            yield chunk, collate([dataset[i] for i in chunk])


def predict(
    dataset: DriveE2EDataset | FeatureCache,
    planner: Planner,
    on_samples: Callable[[int], None] | None = None,
) -> pa.Table:
    """Every sample's plan as a predictions table: of a Dataset's samples, or of a feature
    cache's (the same samples, its batches gathered from memory)."""
    columns: dict[str, list] = {name: [] for name in PREDICTION_SCHEMA.names}
    for chunk, batch in _batches(dataset, list(range(len(dataset)))):
        plans = planner.plan(batch).double()
        for k, index in enumerate(chunk):
            scenario_id, frame = dataset.samples[index]
            columns["scenario_id"].append(scenario_id)
            columns["frame"].append(frame)
            columns["plan_x_m"].append(plans[k, :, 0].tolist())
            columns["plan_y_m"].append(plans[k, :, 1].tolist())
        if on_samples is not None:
            on_samples(len(chunk))
    return pa.table(columns, schema=PREDICTION_SCHEMA)


def write_predictions(path: Path, table: pa.Table) -> None:
    buffer = io.BytesIO()
    pq.write_table(table, buffer)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    store.write_bytes_atomic(Path(path), buffer.getvalue())


def read_predictions(
    path: Path, dataset: DriveE2EDataset | FeatureCache
) -> dict[int, torch.Tensor]:
    """Plans `(T, 2)` by dataset index; one error naming the file, the row and what was
    expected for an unknown frame, a wrong shape or a value that is not finite."""
    path = Path(path)
    if not path.is_file():
        raise DriveE2EError(f"{path}: no such predictions file")
    try:
        table = pq.read_table(path)
    except Exception as error:  # pyarrow raises several types for a damaged file
        raise DriveE2EError(f"{path}: not a readable Parquet file ({error})") from None
    return plans_of(table, dataset, str(path))


def plans_of(
    table: pa.Table, dataset: DriveE2EDataset | FeatureCache, source: str
) -> dict[int, torch.Tensor]:
    """A predictions table's plans `(T, 2)` by `dataset` index (`read_predictions`'s checks;
    `source` names the table in errors)."""
    missing = [n for n in PREDICTION_SCHEMA.names if n not in table.column_names]
    if missing:
        raise DriveE2EError(
            f"{source}: column {missing[0]!r} is missing; expected {', '.join(PREDICTION_SCHEMA.names)}"
        )
    where = {sample: k for k, sample in enumerate(dataset.samples)}
    steps = dataset.horizons.future_steps
    plans: dict[int, torch.Tensor] = {}
    data = table.select(PREDICTION_SCHEMA.names).to_pydict()
    for row, (scenario_id, frame, xs, ys) in enumerate(
        zip(data["scenario_id"], data["frame"], data["plan_x_m"], data["plan_y_m"], strict=True)
    ):
        index = where.get((scenario_id, frame))
        if index is None:
            raise DriveE2EError(
                f"{source} row {row}: ({scenario_id!r}, frame {frame}) is no sample of split "
                f"{dataset.split!r} of {dataset.manifest}"
            )
        if xs is None or ys is None or len(xs) != steps or len(ys) != steps:
            raise DriveE2EError(
                f"{source} row {row}: plan_x_m and plan_y_m have {0 if xs is None else len(xs)} "
                f"and {0 if ys is None else len(ys)} values, expected {steps} each"
            )
        if not all(v is not None and math.isfinite(v) for v in (*xs, *ys)):
            raise DriveE2EError(f"{source} row {row}: a planned coordinate is not a finite number")
        if index in plans:
            raise DriveE2EError(
                f"{source} row {row}: ({scenario_id!r}, frame {frame}) appears twice"
            )
        plans[index] = torch.tensor([xs, ys], dtype=torch.float64).T
    return plans


def score(
    dataset: DriveE2EDataset | FeatureCache,
    plans: dict[int, torch.Tensor],
    conventions: Sequence[str] = ("stp3",),
    on_samples: Callable[[int], None] | None = None,
) -> dict[str, dict[str, dict[str, float]]]:
    """Metrics per convention, overall (`all`) and per behaviour category, over the samples
    that have a plan: of a Dataset's samples, or of the scoring feature cache's
    (`loaders.cache.SCORING`: the same values, gathered from memory). Each sample's errors and
    collisions are computed once, whatever the conventions and categories."""
    # sums of plain tensors, not the torchmetrics Metric: its import (with scipy) was more than
    # half of the command on 2 cores
    from drivee2e_data.metrics.openloop import ErrorSums, sample_errors

    for convention in conventions:
        if convention not in CONVENTIONS:
            raise DriveE2EError(
                f"convention {convention!r}: expected one of {', '.join(CONVENTIONS)}"
            )
    steps = dataset.horizons.future_steps
    sums: dict[str, ErrorSums] = {}
    counts: dict[str, int] = {}
    for chunk, batch in _batches(dataset, sorted(plans)):
        errors, valid, hits = sample_errors(
            torch.stack([plans[i] for i in chunk]),
            batch["gt_ego_fut_trajs"],
            batch["gt_ego_fut_masks"],
            batch["ego_size"],
            batch["ego_rear_axle_to_centre"],
            batch["gt_agent_fut_boxes"],
            batch["gt_agent_fut_masks"] & batch["gt_boxes_mask"][..., None],
        )
        for category in {"all", *batch["category"]}:
            rows = [k for k, c in enumerate(batch["category"]) if category in ("all", c)]
            sums.setdefault(category, ErrorSums.zeros(steps)).add(
                errors[rows], valid[rows], hits[rows] if hits is not None else None
            )
            counts[category] = counts.get(category, 0) + len(rows)
        if on_samples is not None:
            on_samples(len(chunk))
    ordered = sorted(sums, key=lambda c: (c != "all", c))
    return {
        convention: {
            category: {"samples": counts[category], **sums[category].summary(convention)}
            for category in ordered
        }
        for convention in conventions
    }
