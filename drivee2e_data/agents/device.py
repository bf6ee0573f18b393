"""Where a network runs: a closed-loop agent's from `DRIVEE2E_AGENT_DEVICE` = cpu, cuda, cuda:N
or auto (the default: cuda where torch sees a GPU; a policy server sets it for its process to the
GPU it serves, `evaluate/policy_server.py`), and a training's or an open-loop planner's from
`--device` (`model_device`)."""

from __future__ import annotations

import os

from drivee2e_data.errors import DriveE2EError

AGENT_DEVICE_VARIABLE = "DRIVEE2E_AGENT_DEVICE"


def agent_device() -> str:
    """The device the closed-loop agent runs on (`AGENT_DEVICE_VARIABLE`)."""
    import torch

    chosen = os.environ.get(AGENT_DEVICE_VARIABLE, "auto")
    if chosen == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if chosen != "cpu" and not chosen.startswith("cuda"):
        raise DriveE2EError(f"{AGENT_DEVICE_VARIABLE}={chosen!r}: expected auto, cpu or cuda")
    return chosen


def model_device(chosen: str, model: str) -> str:
    """`train`'s and `predict`'s `--device` resolved for `model`: auto is the camera models on
    the GPU where torch sees one, AD-MLP's small MLP (and constant velocity) on the CPU; cpu,
    cuda and cuda:N as given, where torch sees a GPU for the latter two."""
    import torch

    if chosen == "auto":
        return "cuda" if torch.cuda.is_available() and model in ("camera", "tcp") else "cpu"
    if chosen != "cpu" and not chosen.startswith("cuda"):
        raise DriveE2EError(f"--device {chosen!r}: expected auto, cpu, cuda or cuda:N")
    if chosen.startswith("cuda") and not torch.cuda.is_available():
        raise DriveE2EError(f"--device {chosen}: torch sees no CUDA device here")
    return chosen
