"""Agents by name for `drivee2e evaluate --agent`: the built-in baselines, or any class given
as `MODULE:CLASS` (importable from the working directory), built with the checkpoint path."""

from __future__ import annotations

import importlib
import inspect
import sys
from pathlib import Path
from typing import Any

from drivee2e_data.errors import DriveE2EError

AGENTS = {
    "expert": "drivee2e_data.agents.expert:LogReplayExpert",
    "constant-velocity": "drivee2e_data.agents.constant_velocity:ConstantVelocityAgent",
    "admlp": "drivee2e_data.agents.admlp:ADMLPAgent",
    "camera": "drivee2e_data.agents.camera:CameraAgent",
    "tcp": "drivee2e_data.agents.tcp:TCPAgent",
}


def resolve(spec: str) -> type:
    """The agent class of a built-in name or `MODULE:CLASS`."""
    target = AGENTS.get(spec, spec)
    module_name, _, class_name = target.partition(":")
    if not class_name:
        raise DriveE2EError(f"agent {spec!r}: expected one of {', '.join(AGENTS)} or MODULE:CLASS")
    if "" not in sys.path and str(Path.cwd()) not in sys.path:
        # a user's module next to where they run; last, so that from a checkout its
        # `drivee2e_data/` does not shadow the installed package in the pool's spawned workers
        # (they take this process's path)
        sys.path.append(str(Path.cwd()))
    try:
        module = importlib.import_module(module_name)
    except ImportError as error:
        raise DriveE2EError(f"agent {spec!r}: cannot import {module_name!r} ({error})") from None
    agent_class = getattr(module, class_name, None)
    if not inspect.isclass(agent_class):
        raise DriveE2EError(f"agent {spec!r}: {module_name} has no class {class_name!r}")
    for attribute in ("setup", "act"):
        if not callable(getattr(agent_class, attribute, None)):
            raise DriveE2EError(f"agent {spec!r}: {class_name} has no method {attribute}()")
    return agent_class


def build(spec: str, checkpoint: Path | None = None, network: bool = True) -> Any:
    """An agent instance: built with `checkpoint` when its constructor takes one; with
    `network=False`, without loading its network where the constructor allows (an agent
    served by a policy server: its network runs there)."""
    agent_class = resolve(spec)
    parameters = inspect.signature(agent_class).parameters
    if checkpoint is not None and "checkpoint" not in parameters:
        raise DriveE2EError(f"agent {spec!r} takes no checkpoint")
    options = {} if network or "network" not in parameters else {"network": False}
    agent = agent_class(checkpoint, **options) if "checkpoint" in parameters else agent_class()
    for attribute, default in (("name", spec), ("sensors", ()), ("image_size", None)):
        if not hasattr(agent, attribute):
            setattr(agent, attribute, default)
    return agent
