"""A residual image trunk (He et al., "Deep Residual Learning for Image Recognition", 2016): the
basic-block network, ResNet-18's shape by default, randomly initialised (no downloaded weights).

Written here rather than taken from torchvision: torchvision's PyPI wheels are built against
PyPI's CUDA torch, and beside the CPU build of torch this project installs on machines without a
GPU they fail to import (their compiled operators do not register).
"""

from __future__ import annotations

import torch
from torch import nn

RESNET18_BLOCKS = (2, 2, 2, 2)
RESNET18_WIDTH = 64  # channels of the first stage


class BasicBlock(nn.Module):
    """Two 3x3 convolutions with batch norm, added to the input (through a strided 1x1
    convolution where the size or the channels change)."""

    def __init__(self, inputs: int, outputs: int, stride: int) -> None:
        super().__init__()
        self.residual = nn.Sequential(
            nn.Conv2d(inputs, outputs, 3, stride, 1, bias=False), nn.BatchNorm2d(outputs),
            nn.ReLU(inplace=True),
            nn.Conv2d(outputs, outputs, 3, 1, 1, bias=False), nn.BatchNorm2d(outputs),
        )  # fmt: skip
        self.shortcut: nn.Module = nn.Identity()
        if stride != 1 or inputs != outputs:
            self.shortcut = nn.Sequential(
                nn.Conv2d(inputs, outputs, 1, stride, bias=False), nn.BatchNorm2d(outputs)
            )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.relu(self.residual(x) + self.shortcut(x))


class ResNet(nn.Module):
    """Images `(B, 3, H, W)` to features `(B, 8 * width)`: a 7x7 stride-2 stem and a 3x3
    stride-2 max pool, four stages of `blocks` basic blocks with `width`, 2, 4 and 8 times
    `width` channels (the last three halving the size), global average pooling. He (fan-out)
    initialisation; each block's last batch norm starts at zero, so that every block starts as
    the identity (Goyal et al. 2017), which trains a deep net from scratch more steadily."""

    def __init__(
        self, blocks: tuple[int, ...] = RESNET18_BLOCKS, width: int = RESNET18_WIDTH
    ) -> None:
        super().__init__()
        self.features = width * 2 ** (len(blocks) - 1)
        layers: list[nn.Module] = [
            nn.Conv2d(3, width, 7, 2, 3, bias=False), nn.BatchNorm2d(width),
            nn.ReLU(inplace=True), nn.MaxPool2d(3, 2, 1),
        ]  # fmt: skip
        channels = width
        for stage, count in enumerate(blocks):
            outputs = width * 2**stage
            for block in range(count):
                stride = 2 if stage > 0 and block == 0 else 1
                layers.append(BasicBlock(channels, outputs, stride))
                channels = outputs
        layers += [nn.AdaptiveAvgPool2d(1), nn.Flatten()]
        self.body = nn.Sequential(*layers)
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(module, nn.BatchNorm2d):
                nn.init.ones_(module.weight)
                nn.init.zeros_(module.bias)
        for module in self.modules():
            if isinstance(module, BasicBlock):
                nn.init.zeros_(module.residual[-1].weight)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.body(images)
