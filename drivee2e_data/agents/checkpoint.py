"""Checkpoints of the trained baselines: one torch file holding the model, the optimiser, the
options and the epochs done, written atomically after every epoch so training resumes."""

from __future__ import annotations

import os
import pickle
from pathlib import Path
from typing import Any

import torch

from drivee2e_data.errors import DriveE2EError


def save(path: Path, document: dict[str, Any]) -> None:
    """Write `document` to `path` through a temporary name in the same folder."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.{os.getpid()}.partial")
    torch.save(document, partial)
    os.replace(partial, path)


def load(path: Path, kind: str, maker: str) -> dict[str, Any]:
    """The checkpoint at `path`, which must be of `kind` (`maker` says what writes one)."""
    saved = _read(path)
    if not isinstance(saved, dict) or saved.get("kind") != kind:
        raise DriveE2EError(f"{path}: not a {kind} checkpoint ({maker} writes one)")
    return saved


def resume_state(
    path: Path, options: dict[str, Any], samples: int, header: dict[str, Any] | None = None
) -> dict[str, Any] | None:
    """The saved checkpoint when `path` holds one made with the same options (the epoch count
    aside), data size and `header` (the model's kind and shapes); None when there is none; an
    error when it was made otherwise."""
    if not path.is_file():
        return None
    saved = _read(path)
    if not isinstance(saved, dict) or "options" not in saved or "samples" not in saved:
        raise DriveE2EError(f"{path}: not a checkpoint of this trainer; choose another --out")
    same = {k: v for k, v in saved["options"].items() if k != "epochs"} == {
        k: v for k, v in options.items() if k != "epochs"
    }
    if not same or saved["samples"] != samples:
        raise DriveE2EError(
            f"{path}: made with other options or data ({saved['options']}, {saved['samples']} "
            "samples); delete it or choose another --out"
        )
    wanted = _plain(header or {})
    other = {
        key: saved.get(key) for key, value in wanted.items() if _plain(saved.get(key)) != value
    }
    if other:
        here = {key: wanted[key] for key in other}
        raise DriveE2EError(
            f"{path}: a model of other shapes ({other}; this training's: {here}); delete it or "
            "choose another --out"
        )
    return saved


def _plain(value: Any) -> Any:
    """`value` with its tuples as lists, as a checkpoint may give them back either way."""
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    return value


def _read(path: Path) -> Any:
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError, EOFError, ValueError, pickle.UnpicklingError) as error:
        first_line = (
            str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        )
        raise DriveE2EError(f"{path}: not a readable checkpoint ({first_line})") from None
