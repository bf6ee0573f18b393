"""JPEG decoding for samples: on the CPU with OpenCV, at a reduced size straight from the DCT
where the target size allows it (1/2, 1/4, 1/8), or a batch on the GPU with nvJPEG through
torchvision; either way an image smaller than the logged one is its area reduction. Images come
out RGB, `(3, H, W)` uint8.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import cv2
import numpy as np
import torch
from numpy.typing import NDArray

# OpenCV decodes at 1/r of the full size without decoding the full image first
_REDUCED = {
    1: cv2.IMREAD_COLOR,
    2: cv2.IMREAD_REDUCED_COLOR_2,
    4: cv2.IMREAD_REDUCED_COLOR_4,
    8: cv2.IMREAD_REDUCED_COLOR_8,
}


def reduction(full_size: tuple[int, int], target_size: tuple[int, int]) -> int:
    """The largest JPEG reduction (8, 4, 2 or 1) that divides `full_size` (width, height)
    exactly and whose result is still at least `target_size`.

    A reduction that does not divide a side ends it in a partial block: 1600x900 at 1/8 decodes
    to 113 rows for 112.5 rows' worth of image, its last row half padding, and resized to the
    target the image came out stretched by 0.44% (half a row at its foot), 27 dB against the
    area reduction of the full image where a crosswalk's stripes cross it; 1/4 gives that
    reduction within 42 dB (docs/loaders.md)."""
    width, height = full_size
    for factor in (8, 4, 2):
        if width % factor or height % factor:
            continue
        if width // factor >= target_size[0] and height // factor >= target_size[1]:
            return factor
    return 1


def jpeg_size(jpeg: bytes | NDArray[np.uint8]) -> tuple[int, int]:
    """A JPEG's (width, height) read from its frame header, without decoding it."""
    data = bytes(jpeg)
    position = 2  # after the start of image
    while position + 9 <= len(data):
        if data[position] != 0xFF:
            break
        marker = data[position + 1]
        if marker == 0xFF:  # a fill byte
            position += 1
            continue
        # the start-of-frame markers (baseline, progressive, ...): not C4, C8, CC
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            height = int.from_bytes(data[position + 5 : position + 7], "big")
            width = int.from_bytes(data[position + 7 : position + 9], "big")
            return width, height
        position += 2 + int.from_bytes(data[position + 2 : position + 4], "big")
    raise ValueError("not a JPEG with a frame header")


def decode_cpu(
    jpeg: bytes | NDArray[np.uint8],
    full_size: tuple[int, int],
    target_size: tuple[int, int] | None = None,
) -> NDArray[np.uint8]:
    """One JPEG as a contiguous RGB array `(3, H, W)` at `target_size` (width, height)."""
    target = target_size or full_size
    buffer = np.frombuffer(jpeg, np.uint8)
    image = cv2.imdecode(buffer, _REDUCED[reduction(full_size, target)])
    if image is None:
        raise ValueError("not a decodable JPEG")
    if (image.shape[1], image.shape[0]) != target:
        image = cv2.resize(image, target, interpolation=cv2.INTER_AREA)
    rgb = np.empty((3, target[1], target[0]), np.uint8)
    for channel in range(3):  # BGR -> planar RGB in one pass, no intermediate copy
        rgb[channel] = image[:, :, 2 - channel]
    return rgb


def decode_batch(
    jpegs: Sequence[torch.Tensor],
    full_size: tuple[int, int],
    target_size: tuple[int, int] | None = None,
    device: str | torch.device = "cpu",
) -> torch.Tensor:
    """Decode JPEGs (1-D uint8 tensors) into `(len, 3, H, W)` uint8 on `device`: nvJPEG through
    torchvision on a CUDA device, OpenCV otherwise."""
    device = torch.device(device)
    target = target_size or full_size
    if device.type != "cuda":
        return torch.stack(
            [torch.from_numpy(decode_cpu(j.numpy(), full_size, target)) for j in jpegs]
        ).to(device)
    try:
        from torchvision.io import decode_jpeg
        from torchvision.transforms.v2.functional import resize
    except ImportError:
        raise ImportError(
            "decoding on the GPU needs torchvision built for this torch: pip install torchvision"
        ) from None
    images = decode_jpeg(list(jpegs), device=device)
    height, width = images[0].shape[-2:]
    if (width, height) == target:
        return torch.stack(images)
    if width >= target[0] and height >= target[1]:  # the area reduction, as `decode_cpu` gives
        return torch.stack([area_resize(image, target) for image in images])
    return torch.stack([resize(image, [target[1], target[0]], antialias=True) for image in images])


@functools.lru_cache(maxsize=16)
def area_weights(source: int, target: int, device: torch.device) -> torch.Tensor:
    """`(target, source)` float32: row i the share of each of `source` pixels in the i-th of
    `target` equal intervals spanning them (`target` <= `source`), each row summing to one.
    Made once per sizes and device (made afresh for each image, they had cost the GPU path
    four times its decode)."""
    edges = torch.arange(target + 1, dtype=torch.float64) * (source / target)
    left = torch.arange(source, dtype=torch.float64)[None]
    overlap = torch.minimum(edges[1:, None], left + 1) - torch.maximum(edges[:-1, None], left)
    return (overlap.clamp(min=0.0) * (target / source)).to(device, torch.float32)


def area_resize(image: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """`image` `(C, H, W)` uint8 reduced to `size` (width, height, each no larger than the
    image's) by area averaging, on the image's device: OpenCV's `INTER_AREA` within a level
    (tested), where an antialiased bilinear resize weighs each pixel's neighbours too."""
    rows = area_weights(image.shape[-2], size[1], image.device)
    columns = area_weights(image.shape[-1], size[0], image.device)
    reduced = rows @ image.to(torch.float32) @ columns.T
    return reduced.round_().clamp_(0, 255).to(torch.uint8)
