"""Light and weather: the sun's direction from the clip's UTC time and the map's WGS84 origin,
light colour and ambient per weather and time of day, and post-processing of a rendered image
with its depth buffer (fog, rain streaks and wet-road darkening, low light with noise and
headlight falloff at night). Deterministic: noise and streaks come from a seed.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.hdmap import GeoOrigin
from drivee2e_data.scenario import Conditions, Weather
from drivee2e_data.sun import sun_position

# metres of visibility (distance at which contrast falls to 5%); None: clear air
VISIBILITY_M = {Weather.FOG: 70.0, Weather.RAIN: 400.0, Weather.OVERCAST: 3000.0, Weather.CLOUDY: None,
                Weather.CLEAR: None, Weather.WET: None}  # fmt: skip
FOG_RGB = np.array([200.0, 202.0, 205.0])
NIGHT_GAIN = 0.22  # scene brightness at night before artificial light
NIGHT_NOISE_SIGMA = 6.0  # sensor noise (8-bit levels) in low light
HEADLIGHT_REACH_M = 35.0
WET_DARKENING = 0.82  # road and ground pixels darken this much when wet or raining
RAIN_STREAKS = 180
RAIN_OPACITY = 0.35
RAIN_RGB = 220  # the streaks' grey level


@dataclass(frozen=True)
class Lighting:
    direction: tuple[float, float, float]  # unit vector towards the light, world frame (ENU)
    colour: tuple[float, float, float]
    ambient: float
    diffuse: float
    night: bool


def lighting(conditions: Conditions, origin: GeoOrigin) -> Lighting:
    azimuth, elevation = sun_position(conditions.start_time_utc, origin)
    night = elevation < math.radians(-4)
    if night:  # street lights from above
        direction = (0.0, 0.0, 1.0)
        return Lighting(direction, (1.0, 0.85, 0.6), 0.5, 0.4, True)
    lift = max(elevation, math.radians(5))
    direction = (
        math.sin(azimuth) * math.cos(lift),
        math.cos(azimuth) * math.cos(lift),
        math.sin(lift),
    )
    low_sun = elevation < math.radians(15)
    colour = (1.0, 0.78, 0.55) if low_sun else (1.0, 0.98, 0.94)
    overcast = conditions.weather in (Weather.OVERCAST, Weather.RAIN, Weather.FOG)
    return Lighting(direction, colour, 0.75 if overcast else 0.55, 0.3 if overcast else 0.6, False)


def post_process(
    rgb: NDArray[np.uint8],
    depth_m: NDArray[np.float32],
    conditions: Conditions,
    light: Lighting,
    seed: int,
    headlights: bool = False,
) -> NDArray[np.uint8]:
    """The weather and light of `conditions` applied to an image with its metric depth.

    By day the work stays in 8 bits with OpenCV's fused operations (a 1600x900 image takes a
    few milliseconds); night, with its gain, headlights and noise, goes through floats."""
    import cv2

    visibility = VISIBILITY_M[conditions.weather]
    wet = conditions.weather in (Weather.RAIN, Weather.WET)
    if visibility is None and not wet and not light.night:
        return rgb  # clear air by day: the render as is
    rng = np.random.default_rng(seed)
    image = np.ascontiguousarray(rgb)
    if wet:
        image = image.copy()
        lower = image[image.shape[0] // 2 :]
        surface = depth_m[image.shape[0] // 2 :] < 150.0  # road and ground, mostly
        _darken(lower, surface)
    if visibility is not None:
        # OpenCV's exp: a third the time of numpy's (depth is at most the far plane, or inf,
        # whose transmission is 0 either way)
        transmission = cv2.exp(
            np.multiply(depth_m, np.float32(-3.0 / visibility), dtype=np.float32)
        )
        fog_rgb = np.round(FOG_RGB * (NIGHT_GAIN if light.night else 1.0)).astype(np.uint8)
        fog = _uniform_image(image.shape, tuple(fog_rgb.tolist()))
        image = cv2.blendLinear(image, fog, transmission, 1.0 - transmission)
    if light.night:
        night = image.astype(np.float32)
        night *= NIGHT_GAIN
        if headlights:
            falloff = np.multiply(depth_m, np.float32(-1.0 / HEADLIGHT_REACH_M), dtype=np.float32)
            falloff += np.float32(1.0)
            np.clip(falloff, 0.0, 1.0, out=falloff)
            falloff *= _headlight_cone(*depth_m.shape)
            falloff *= np.float32(3.0)
            falloff += np.float32(1.0)
            night *= falloff[..., None]
        night += sensor_noise(night.shape, rng) * np.float32(NIGHT_NOISE_SIGMA)
        np.clip(night, 0, 255, out=night)
        image = night.astype(np.uint8)
    if conditions.weather == Weather.RAIN:
        image = _rain(image, rng)
    return image


@functools.lru_cache(maxsize=4)
def _headlight_cone(height: int, width: int) -> NDArray[np.float32]:
    """(H, W) the headlights' reach across the image: 1 at the centre column falling to 0 at
    the sides, over the rows below 45% of the height; made once per size (read-only)."""
    columns = np.abs(np.arange(width) - width / 2) / (width / 2)
    cone = (
        np.clip(1.0 - columns, 0.0, 1.0)[None, :] * (np.arange(height)[:, None] > height * 0.45)
    ).astype(np.float32)
    cone.flags.writeable = False
    return cone


def _darken(image: NDArray[np.uint8], where: NDArray[np.bool_]) -> None:
    """Darkens `image` in place by `WET_DARKENING` where `where` (H, W) holds; OpenCV's masked
    copy, 50 times faster than numpy's copyto with a broadcast mask."""
    import cv2

    cv2.copyTo(cv2.convertScaleAbs(image, alpha=WET_DARKENING), where.view(np.uint8), image)


@functools.lru_cache(maxsize=8)
def _uniform_image(shape: tuple[int, ...], rgb: tuple[int, int, int]) -> NDArray[np.uint8]:
    """A read-only image of one colour, made once per size (filling one takes 7 ms at
    1024x768, as long as the blend it feeds)."""
    image = np.empty(shape, np.uint8)
    image[:] = rgb
    image.flags.writeable = False
    return image


NOISE_POOL_VALUES = 1 << 23  # 8.4 M standard-normal values (32 MiB), made once per process


@functools.cache
def noise_pool() -> NDArray[np.float32]:
    return np.random.default_rng(0x5EED).standard_normal(NOISE_POOL_VALUES, dtype=np.float32)


def noise_offset(size: int, rng: np.random.Generator) -> int | None:
    """Where `size` values of noise start in the pool, drawn from `rng`; None for more than half
    the pool (those are drawn afresh)."""
    if size > NOISE_POOL_VALUES // 2:
        return None
    return int(rng.integers(NOISE_POOL_VALUES - size + 1))


def sensor_noise(shape: tuple[int, ...], rng: np.random.Generator) -> NDArray[np.float32]:
    """Standard-normal noise of `shape`: a window of a fixed pool at an offset drawn from `rng`
    (a 1024x768 image's noise in 2 ms, against 36 ms drawn afresh), so the same seed gives the
    same noise in any process; images larger than the pool draw theirs afresh."""
    size = math.prod(shape)
    start = noise_offset(size, rng)
    if start is None:
        return rng.standard_normal(shape, dtype=np.float32)
    return noise_pool()[start : start + size].reshape(shape)


def _rain(image: NDArray[np.uint8], rng: np.random.Generator) -> NDArray[np.uint8]:
    """Bright, slanted streaks blended over the image."""
    import cv2

    streaks = rain_streaks(image.shape[:2], rng)
    bright = np.full_like(image, RAIN_RGB)
    return cv2.blendLinear(image, bright, 1.0 - streaks, streaks)


def rain_streaks(shape: tuple[int, int], rng: np.random.Generator) -> NDArray[np.float32]:
    """(H, W) weights in [0, RAIN_OPACITY] of `RAIN_STREAKS` slanted, anti-aliased streaks."""
    import cv2

    streaks = np.zeros(shape, np.float32)
    height, width = shape
    for _ in range(RAIN_STREAKS):
        x, y = int(rng.integers(width)), int(rng.integers(height))
        length = int(rng.integers(height // 30, height // 10))
        cv2.line(streaks, (x, y), (x + length // 6, y + length), 1.0, 1, cv2.LINE_AA)
    streaks *= RAIN_OPACITY
    return streaks
