"""The image models' training augmentation: a brightness gain per image, drawn from a counter
saved with the weights (the `augment_step` buffer), so a resumed training draws what an
uninterrupted one would, on any device.

The counter is read from a copy kept on the host: reading the buffer itself where the model
lives on a GPU (`int(buffer)`) would wait for every step queued there, and copying the gains
there from pageable memory would wait too; either way the CPU could not prepare the next step
while the GPU ran this one (the GPU's training was bound by that wait)."""

from __future__ import annotations

import torch
from torch import nn

GAIN_RANGE = (0.7, 1.3)  # brightness gains drawn uniformly from this range
COUNTER = "augment_step"  # the buffer's name in the models' state dicts (their checkpoints)
_HOST_COUNTER = "_augment_step_on_host"


def add_counter(model: nn.Module) -> None:
    """Give `model` the saved counter the gains are drawn from (call in its `__init__`)."""
    model.register_buffer(COUNTER, torch.zeros((), dtype=torch.int64))
    # weights loaded later carry their own count: the host's copy is read again from them
    model.register_load_state_dict_post_hook(_forget_host_counter)


def _forget_host_counter(model: nn.Module, incompatible: object) -> None:
    del incompatible
    model.__dict__.pop(_HOST_COUNTER, None)


def brightness_gains(
    model: nn.Module, shape: tuple[int, ...], device: torch.device
) -> torch.Tensor:
    """The next training step's gains `shape` on `device`, drawn from the model's counter (which
    this advances): the same numbers on every device."""
    step = model.__dict__.get(_HOST_COUNTER)
    if step is None:  # once a training (or after loading weights): the buffer's own value
        step = int(getattr(model, COUNTER))
    generator = torch.Generator().manual_seed(step)
    gain = torch.empty(shape).uniform_(*GAIN_RANGE, generator=generator)
    model.__dict__[_HOST_COUNTER] = step + 1
    getattr(model, COUNTER).fill_(step + 1)  # queued where the buffer lives: no wait
    if device.type == "cuda":  # from pinned memory the copy is queued too
        return gain.pin_memory().to(device, non_blocking=True)
    return gain.to(device)
