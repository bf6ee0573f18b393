"""Where a closed-loop agent runs its network: `DRIVEE2E_AGENT_DEVICE` = cpu, cuda, cuda:N or
auto (the default: cuda where torch sees a GPU). A policy server sets it for its process to the
GPU it serves (`evaluate/policy_server.py`)."""

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
