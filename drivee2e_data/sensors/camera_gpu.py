"""A frame's camera images finished on a torch device (a GPU): weather and light, the resize from
the drawn size to the camera's, and JPEG encoding (nvJPEG through torchvision on CUDA).

The CPU path (`camera.with_conditions`, `camera.encode_jpeg`) is the reference; this one gives
images within one or two 8-bit levels of it before JPEG (different rounding in the resize), and
the same bytes every time for the same inputs on the same device.
"""

from __future__ import annotations

import functools
import sys

from drivee2e_data.errors import DriveE2EError
from drivee2e_data.sensors.camera import CameraFrame, encode_jpeg, has_headlights, noise_seed
from drivee2e_data.sim import conditions_torch
from drivee2e_data.sim.conditions import Exposure
from drivee2e_data.sim.gl_readback import contiguous_rgb
from drivee2e_data.sim.world import World

POST_PROCESS_DEVICES = ("cpu", "cuda")


def cuda_available() -> bool:
    """Whether torch sees a CUDA device here."""
    try:
        import torch
    except ImportError:
        return False
    return bool(torch.cuda.is_available())


def check_device(device: str) -> None:
    if device not in POST_PROCESS_DEVICES:
        raise DriveE2EError(
            f"post-process device {device!r}: expected one of {', '.join(POST_PROCESS_DEVICES)}"
        )
    if device == "cuda" and not cuda_available():
        raise DriveE2EError("post-process device 'cuda': torch sees no CUDA device here")


def prepare(device: str) -> None:
    """Start CUDA in this process (for `device` "cuda"): before pybullet's EGL plugin makes its
    context, since CUDA started while an NVIDIA EGL context is current hung a worker."""
    if device == "cuda":
        import torch

        torch.cuda.init()
        torch.zeros(1, device=device)  # the primary context, made now
        _nvjpeg()  # torchvision's import (seconds), here rather than in the first frame


def cuda_started() -> bool:
    """Whether this process has started CUDA through torch."""
    torch = sys.modules.get("torch")
    return torch is not None and bool(torch.cuda.is_initialized())


def finish(
    world: World, views: list[CameraFrame], frame: int, device: str, exposures: list[Exposure]
) -> list:
    """Each view's RGB at its camera's size under the clip's weather and light, exposed by its
    `exposures` (`camera.camera_exposure`, metered on the host), as (3, H, W) uint8 tensors on
    `device`; the seeds and headlights of `camera.with_conditions`."""
    import torch
    import torch.nn.functional as functional

    scenario = world.scenario
    images = []
    for view, exposed in zip(views, exposures, strict=True):
        rgb = torch.from_numpy(contiguous_rgb(view.rgb)).to(device, non_blocking=True)
        depth = torch.from_numpy(view.depth_m).to(device, non_blocking=True)
        image = conditions_torch.post_process(
            rgb, depth, scenario.conditions, world.lighting,
            noise_seed(scenario.scenario_id, frame, view.camera),
            headlights=has_headlights(view.camera), shaded=world.renderer == "gl",
            gain=exposed.gain,
        )  # fmt: skip
        chw = image.permute(2, 0, 1)
        size = (view.camera.height, view.camera.width)
        if tuple(chw.shape[1:]) != size:
            # cv2.INTER_LINEAR's sampling: pixel centres, no antialiasing, edges clamped
            resized = functional.interpolate(
                chw[None].float(), size=size, mode="bilinear", align_corners=False
            )[0]
            chw = torch.clamp(torch.round(resized), 0, 255).to(torch.uint8)
        images.append(chw.contiguous())
    if device == "cuda":
        torch.cuda.synchronize()
    return images


def encode(images: list, quality: int) -> list[bytes]:
    """JPEG bytes of (3, H, W) uint8 RGB tensors: one nvJPEG batch where they are on a CUDA
    device and torchvision is installed, else OpenCV on the CPU."""
    if images and images[0].is_cuda and _nvjpeg():
        from torchvision.io import encode_jpeg as nvjpeg

        return [bytes(data.cpu().numpy()) for data in nvjpeg(images, quality=quality)]
    return [encode_jpeg(image.permute(1, 2, 0).cpu().numpy(), quality) for image in images]


@functools.cache
def _nvjpeg() -> bool:
    try:
        from torchvision.io import encode_jpeg  # noqa: F401
    except ImportError:
        return False
    return True
