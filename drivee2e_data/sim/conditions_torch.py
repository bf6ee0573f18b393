"""`conditions.post_process` on torch tensors, so that a GPU applies a frame's weather and light.

The same operations in the same order, with the same seeded random draws (noise from the same
pool, rain streaks drawn by OpenCV on the CPU), rounded as OpenCV rounds: on the CPU the result
equals `conditions.post_process` within one 8-bit level (float order of operations), on a GPU
it is the same for the same inputs every time.
"""

from __future__ import annotations

import functools

import numpy as np

from drivee2e_data.scenario import Conditions, Weather
from drivee2e_data.sim.conditions import (
    BLEND_EPSILON,
    FOG_RGB,
    HEADLIGHT_REACH_M,
    NIGHT_GAIN,
    RAIN_RGB,
    VISIBILITY_M,
    WET_DARKENING,
    Lighting,
    noise_levels,
    noise_offset,
    noise_pool,
    rain_streaks,
)


def post_process(rgb, depth_m, conditions: Conditions, light: Lighting, seed: int,
                 headlights: bool = False, shaded: bool = False, gain: float = 1.0):  # fmt: skip
    """`rgb` (H, W, 3) uint8 and `depth_m` (H, W) float32 tensors on one device -> (H, W, 3)
    uint8 on that device, under the weather and light of `conditions`; with `shaded` (the GL
    renderer drew them), only the rain's streaks and the low-light noise (as
    `conditions.post_process`); `gain`, the camera's exposure, before the noise."""
    import torch

    visibility = None if shaded else VISIBILITY_M[conditions.weather]
    wet = not shaded and conditions.weather in (Weather.RAIN, Weather.WET)
    rain = conditions.weather == Weather.RAIN
    if visibility is None and not wet and not light.night and not rain:
        return _expose(rgb, gain)
    rng = np.random.default_rng(seed)
    image = rgb
    if wet:
        half = image.shape[0] // 2
        lower = image[half:]
        darker = _round_to_uint8(lower.float() * WET_DARKENING)
        surface = (depth_m[half:] < 150.0)[..., None]
        image = torch.cat([image[:half], torch.where(surface, darker, lower)])
    if visibility is not None:
        transmission = torch.exp(torch.clamp(depth_m, max=1e4) * (-3.0 / visibility))[..., None]
        fog_rgb = np.round(FOG_RGB * (NIGHT_GAIN if light.night else 1.0)).astype(np.float32)
        fog = torch.as_tensor(fog_rgb, device=image.device)
        image = _blend(image, fog, transmission)
    image = _expose(image, gain)
    if light.night:
        night = image.float() * (1.0 if shaded else NIGHT_GAIN)
        if headlights and not shaded:
            night = night * _headlight_gain(depth_m)[..., None]
        start = noise_offset(night.numel(), rng)
        if start is None:
            fresh = noise_levels(rng.standard_normal(tuple(night.shape), dtype=np.float32))
            noise = torch.as_tensor(fresh, device=night.device)
        else:
            noise = _device_pool(str(night.device))[start : start + night.numel()]
        night = night + noise.reshape(night.shape).float()  # whole 8-bit levels
        image = torch.clamp(night, 0, 255).to(torch.uint8)  # truncates, as numpy's astype does
    if conditions.weather == Weather.RAIN:
        streaks = torch.as_tensor(rain_streaks(tuple(image.shape[:2]), rng), device=image.device)
        image = _blend(
            image, torch.tensor(float(RAIN_RGB), device=image.device), 1.0 - streaks[..., None]
        )
    return image


def _expose(image, gain: float):
    """`conditions.expose`: times the gain, rounded (half to even, as OpenCV) and saturated."""
    if gain == 1.0:
        return image
    return _round_to_uint8(image.float() * gain)


def _blend(image, colour, weight):
    """OpenCV's blendLinear of `image` (weight `weight`) with a constant `colour` (1 - weight)."""
    blended = (image.float() * weight + colour * (1.0 - weight)) / (1.0 + BLEND_EPSILON)
    return _round_to_uint8(blended)


def _round_to_uint8(values):
    import torch

    return torch.clamp(torch.round(values), 0, 255).to(torch.uint8)


def _headlight_gain(depth_m):
    """1 + 3 x the front camera's headlight falloff: a cone over the lower image, fading to
    nothing at `HEADLIGHT_REACH_M`."""
    import torch

    height, width = depth_m.shape
    columns = torch.abs(torch.arange(width, device=depth_m.device, dtype=torch.float64) - width / 2)
    cone = torch.clamp(1.0 - columns / (width / 2), 0.0, 1.0)[None, :] * (
        torch.arange(height, device=depth_m.device)[:, None] > height * 0.45
    )
    falloff = torch.clamp(1.0 - depth_m / HEADLIGHT_REACH_M, 0.0, 1.0) * cone
    return (1.0 + 3.0 * falloff).to(torch.float32)


@functools.cache
def _device_pool(device: str):
    """The sensor-noise pool of `conditions`, copied to `device` once per process."""
    import torch

    return torch.tensor(noise_pool(), device=device)  # a copy: the pool is read-only
