"""The training loop's checkpoints: written after the last epoch, and before it only once
`CHECKPOINT_EVERY_S` has passed since the last write (each is a resume point)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from torch import nn

from drivee2e_data.agents import training
from drivee2e_data.agents.training import TrainOptions, fit


def _rows() -> dict[str, torch.Tensor]:
    generator = torch.Generator().manual_seed(0)
    return {
        "x": torch.randn(24, 4, generator=generator),
        "y": torch.randn(24, 3, 2, generator=generator),
        "mask": torch.ones(24, 3),
    }


def _predict(model: nn.Module, rows: dict[str, torch.Tensor]) -> torch.Tensor:
    return model(rows["x"]).reshape(-1, 3, 2)


@pytest.mark.parametrize(("every_s", "written"), [(0.0, [1, 2, 3, 4]), (float("inf"), [])])
def test_checkpoints_are_written_when_due_and_after_the_last_epoch(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, every_s: float, written: list[int]
) -> None:
    monkeypatch.setattr(training, "CHECKPOINT_EVERY_S", every_s)
    checkpoint = tmp_path / "model.pt"
    seen: list[int] = []

    def on_epoch(epoch: int, _loss: float) -> None:
        if checkpoint.is_file():
            saved = torch.load(checkpoint, weights_only=True)
            if saved["epoch"] == epoch:
                seen.append(epoch)

    torch.manual_seed(0)
    model = nn.Linear(4, 6)
    result = fit(model, _rows(), _predict, checkpoint, TrainOptions(epochs=5, batch_size=8),
                 {"kind": "toy"}, on_epoch=on_epoch)  # fmt: skip
    # the last epoch's checkpoint is always written (before its callback)
    assert seen == [*written, 5]
    assert result["epoch"] == 5 and len(result["losses"]) == 5
    # the same run again resumes from it: nothing more to train, the same weights
    again = fit(nn.Linear(4, 6), _rows(), _predict, checkpoint, TrainOptions(epochs=5, batch_size=8),
                {"kind": "toy"})  # fmt: skip
    assert again["losses"] == result["losses"]
    assert torch.equal(again["model"]["weight"], result["model"]["weight"])
