"""Light and weather: the sun's direction from the clip's UTC time and the map's WGS84 origin,
light colour and ambient per weather and time of day, what the GL renderer's shaders draw of
them (`ShaderLook`: sky, clouds, shadows, fog, wet surfaces, street lamps and headlights), and
the post-processing of a rendered image: everything for pybullet's renderers (fog, rain streaks
and wet-road darkening, low light with noise and headlight falloff at night), only rain streaks
and sensor noise for the GL renderer. Deterministic: noise and streaks come from a seed.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.hdmap import GeoOrigin
from drivee2e_data.scenario import Conditions, Weather
from drivee2e_data.sim.gl_readback import bgra_under, contiguous_rgb
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
BLEND_EPSILON = 1e-5  # OpenCV's blendLinear divides by w1 + w2 + 1e-5
# Each camera's auto-exposure (`exposure`): the mean grey level (luma, 0-255) it holds a drawn
# image within by day, the range of its gain, and how many columns the meter samples across
EXPOSURE_BAND = (80.0, 100.0)
EXPOSURE_AIM = (82.0, 98.0)  # where it brings an image from outside the band
EXPOSURE_GAINS = (0.5, 3.0)
METER_COLUMNS = 200
LUMA = (0.299, 0.587, 0.114)  # ITU-R BT.601, as OpenCV's grey conversion


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


@dataclass(frozen=True)
class Exposure:
    """A camera's exposure at one frame: the gain on the drawn image's 8-bit values (before the
    sensor's noise and the rain's streaks; 1: as drawn) and the mean grey its meter read."""

    gain: float
    metered: float


def meter_step(width: int) -> int:
    """The pixels between two of the exposure meter's samples along a row (and a column) of an
    image `width` wide: about `METER_COLUMNS` across (1 for an image narrower than that: every
    pixel, as the closed-loop observer's reduced views are metered)."""
    return max(1, round(width / METER_COLUMNS))


def meter(rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
    """The grey levels (luma) the exposure meter reads of an image: a grid of about
    `METER_COLUMNS` pixels across (`meter_step`), the same places of the view whatever size it
    is drawn at."""
    step = meter_step(rgb.shape[1])
    sample = np.asarray(rgb[step // 2 :: step, step // 2 :: step], dtype=np.float32)
    return sample @ np.asarray(LUMA, dtype=np.float32)


def exposure(rgb: NDArray[np.uint8], light: Lighting) -> Exposure:
    """A camera's auto-exposure for a drawn image: it meters the image's mean grey and, where
    that lies outside `EXPOSURE_BAND`, sets the gain that brings the mean just inside the
    band's nearer edge (`EXPOSURE_AIM`, counting the levels that saturate at 255), within
    `EXPOSURE_GAINS`; inside the band the image stays as drawn (a tolerance band, as cameras
    hold one against hunting; a view crossing its edge steps by 2 levels). At night
    the gain only ever lowers a too-bright image: real night stays dark.

    Memoryless: the gain is a function of the frame's own image, so a frame's pixels do not
    depend on which frames were collected before it (segments, `--sensor-hz`, closed loop). A
    camera's AE settles in a few tenths of a second, under the 0.5 s between 2 Hz keyframes;
    the views change smoothly, and so does the gain (docs/twins.md measures it frame to
    frame)."""
    grey = meter(rgb)
    metered = _mean(grey)
    low, high = EXPOSURE_BAND
    if metered > high:
        want = EXPOSURE_AIM[1]
    elif metered < low and not light.night and metered > 0.0:
        want = EXPOSURE_AIM[0]
    else:
        return Exposure(1.0, metered)
    least, most = EXPOSURE_GAINS
    gain = float(np.clip(want / metered, least, most))
    if gain > 1.0 and grey.max() * gain > 255.0:
        # levels that saturate add less than their share: bisect for the gain that reaches
        # `want` counting them (the mean is monotone in the gain), up to the range's top
        low_gain, high_gain = gain, most
        scaled = np.empty_like(grey)
        for _ in range(24):
            middle = 0.5 * (low_gain + high_gain)
            np.multiply(grey, np.float32(middle), out=scaled)
            if _mean(np.minimum(scaled, np.float32(255.0), out=scaled)) < want:
                low_gain = middle
            else:
                high_gain = middle
        gain = high_gain
    return Exposure(gain, metered)


def _mean(values: NDArray[np.float32]) -> float:
    """numpy's `values.mean()` of a float32 array, the same float (its pairwise float32 sum
    over the count, rounded to float32) without `mean`'s dispatch: a bisection takes 24 (a
    bisecting view 0.31 -> 0.25 ms on 2 cores)."""
    total = np.add.reduce(values, axis=None)
    return float(total.dtype.type(total / np.intp(values.size)))


def expose(rgb: NDArray[np.uint8], gain: float) -> NDArray[np.uint8]:
    """An image times its exposure's gain, rounded and saturated in 8 bits (itself at 1). A
    view of the GL renderer's BGRA read stays one (of the scaled BGRA), so that the JPEG
    encoder still takes it without a conversion (`camera.encode_jpeg`)."""
    if gain == 1.0:
        return rgb
    import cv2

    bgra = bgra_under(rgb)
    if bgra is not None:
        return cv2.convertScaleAbs(bgra, alpha=gain)[..., 2::-1]
    return cv2.convertScaleAbs(contiguous_rgb(rgb), alpha=gain)


def post_process(
    rgb: NDArray[np.uint8],
    depth_m: NDArray[np.float32] | None,
    conditions: Conditions,
    light: Lighting,
    seed: int,
    headlights: bool = False,
    shaded: bool = False,
    gain: float = 1.0,
) -> NDArray[np.uint8]:
    """The weather and light of `conditions` applied to an image with its metric depth; with
    `shaded` (the GL renderer drew fog, wet surfaces and night light already), only the rain's
    streaks and the low-light sensor noise, and no depth is needed (None). `gain`: the
    camera's exposure (`exposure`), applied to the scene's light before the sensor's noise.

    By day the work stays in 8 bits with OpenCV's fused operations (a 1600x900 image takes a
    few milliseconds); night, with its gain, headlights and noise, goes through floats."""
    import cv2

    if shaded:
        return _sensor_effects(expose(rgb, gain), conditions, light, seed)
    if depth_m is None:
        raise ValueError("the weather of an unshaded image needs its depth image")
    visibility = VISIBILITY_M[conditions.weather]
    wet = conditions.weather in (Weather.RAIN, Weather.WET)
    if visibility is None and not wet and not light.night:
        return expose(rgb, gain)  # clear air by day: the render as is, exposed
    rng = np.random.default_rng(seed)
    image = contiguous_rgb(rgb)
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
    image = expose(image, gain)
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
        night += sensor_noise(night.shape, rng)
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


# 16.8 M values of noise in 8-bit levels (16 MiB), made once per process: twice a 1600x900 RGB
# image, so the cameras' night noise is a window of it (drawn afresh, it took 100 ms a camera: the
# fog + night clip's post-processing was 615 ms a frame on the H100 host, 0-95 ms on the other
# clips). Whole levels, so that a night image is one saturating 8-bit add (`cv2.add`, about 1 ms
# a camera) instead of a pass through floats (4.4 ms here); the torch path adds the same levels.
NOISE_POOL_VALUES = 1 << 24


def noise_levels(values: NDArray[np.float32]) -> NDArray[np.int8]:
    """Standard-normal `values` as sensor noise in whole 8-bit levels: times
    `NIGHT_NOISE_SIGMA`, rounded, within an int8."""
    levels = np.rint(values * np.float32(NIGHT_NOISE_SIGMA))
    return np.clip(levels, -127, 127).astype(np.int8)


@functools.cache
def noise_pool() -> NDArray[np.int8]:
    """The process's pool of noise levels (`noise_levels` of a fixed seed's normal values)."""
    rng = np.random.default_rng(0x5EED)
    pool = np.empty(NOISE_POOL_VALUES, np.int8)
    block = NOISE_POOL_VALUES // 16  # a 64 MiB float array at once would only be thrown away
    for start in range(0, NOISE_POOL_VALUES, block):
        pool[start : start + block] = noise_levels(rng.standard_normal(block, dtype=np.float32))
    pool.flags.writeable = False
    return pool


def noise_offset(size: int, rng: np.random.Generator) -> int | None:
    """Where `size` values of noise start in the pool, drawn from `rng`; None for more than half
    the pool (those are drawn afresh)."""
    if size > NOISE_POOL_VALUES // 2:
        return None
    return int(rng.integers(NOISE_POOL_VALUES - size + 1))


def sensor_noise(shape: tuple[int, ...], rng: np.random.Generator) -> NDArray[np.int8]:
    """Sensor noise of `shape` in whole 8-bit levels (normal, sigma `NIGHT_NOISE_SIGMA`): a
    window of a fixed pool at an offset drawn from `rng`, so the same seed gives the same noise
    in any process; images larger than half the pool draw theirs afresh."""
    size = math.prod(shape)
    start = noise_offset(size, rng)
    if start is None:
        return _fresh_noise(shape, rng)
    return noise_pool()[start : start + size].reshape(shape)


def _fresh_noise(shape: tuple[int, ...], rng: np.random.Generator) -> NDArray[np.int8]:
    """Noise levels of `shape` drawn from `rng` (an image larger than half the pool)."""
    return noise_levels(rng.standard_normal(shape, dtype=np.float32))


@functools.cache
def _noise_pool_parts() -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """The pool's levels as what they add and what they take away, each uint8 (one of the two
    is 0 at every value): OpenCV adds and subtracts two uint8 images with saturation in one SIMD
    pass each, where adding the int8 levels to a uint8 image converts both (two passes 0.4 ms
    a 1600x900 camera against 2.2 here, the same bytes)."""
    pool = noise_pool()
    parts = (
        np.maximum(pool, 0).astype(np.uint8),
        np.maximum(-pool.astype(np.int16), 0).astype(np.uint8),
    )
    for part in parts:
        part.flags.writeable = False
    return parts


def with_sensor_noise(image: NDArray[np.uint8], rng: np.random.Generator) -> NDArray[np.uint8]:
    """A new image: `image` (C-contiguous) plus `sensor_noise(image.shape, rng)` with
    saturation, the bytes `cv2.add` of the int8 levels gives, as the pool's window of what the
    levels add, then of what they take away (`_noise_pool_parts`)."""
    import cv2

    size = image.size
    start = noise_offset(size, rng)
    if start is None:  # larger than half the pool: drawn afresh, as `sensor_noise` draws them
        return cv2.add(image, _fresh_noise(image.shape, rng), dtype=cv2.CV_8U)
    up, down = (part[start : start + size].reshape(image.shape) for part in _noise_pool_parts())
    noisy = cv2.add(image, up)
    cv2.subtract(noisy, down, dst=noisy)
    return noisy


def _rain(image: NDArray[np.uint8], rng: np.random.Generator) -> NDArray[np.uint8]:
    """Bright, slanted streaks blended over the image: OpenCV's `blendLinear` arithmetic (the
    same bytes), worked out only at the pixels the streaks touch, a few percent of the image
    (a 1600x900 camera in 1.4 ms against 4.4-5.1 for blendLinear over all of it, one thread).
    The streaks are drawn on a canvas kept zeroed in this process (`_streak_canvas`) and
    weighted only where they touch: a fresh canvas scaled whole, as `rain_streaks` gives it,
    had the system zero and map all of its 5.8 MB every camera."""

    canvas = _streak_canvas(image.shape[:2])
    flat = canvas.ravel()
    try:
        _draw_streaks(canvas, rng)
        touched = np.flatnonzero(canvas > 0.0)  # a bool's flatnonzero: a tenth of a float's time
        weight = (flat[touched] * RAIN_OPACITY)[:, None]  # as `rain_streaks` scales them
        flat[touched] = 0.0  # zeroed again for the next image
    except BaseException:
        canvas.fill(0.0)  # whatever was drawn
        raise
    pixels = image.reshape(-1, image.shape[2])
    blended = (pixels[touched] * (1.0 - weight) + np.float32(RAIN_RGB) * weight) / np.float32(
        1.0 + BLEND_EPSILON
    )
    result = image.copy()
    result.reshape(-1, image.shape[2])[touched] = np.clip(np.rint(blended), 0, 255)
    return result


@functools.lru_cache(maxsize=2)
def _streak_canvas(shape: tuple[int, int]) -> NDArray[np.float32]:
    """(H, W) zeros that `_rain` draws its streaks on and zeroes again after each image."""
    return np.zeros(shape, np.float32)


def rain_streaks(shape: tuple[int, int], rng: np.random.Generator) -> NDArray[np.float32]:
    """(H, W) weights in [0, RAIN_OPACITY] of `RAIN_STREAKS` slanted, anti-aliased streaks
    (`_draw_streaks`)."""

    streaks = np.zeros(shape, np.float32)
    _draw_streaks(streaks, rng)
    streaks *= RAIN_OPACITY
    return streaks


def _draw_streaks(canvas: NDArray[np.float32], rng: np.random.Generator) -> None:
    """`RAIN_STREAKS` lines drawn on `canvas` (H, W) at full weight 1, one pixel wide,
    anti-aliased, in order: each from (x, y), x and y uniform over the image, `length` rows long
    (a 30th to a 10th of the height) and leaning a sixth of that to the right. The three numbers
    of all streaks come from one call (numpy draws an array of bounds element by element: the
    same numbers as a call per number) and the lines go to one `polylines` (the same pixels as
    a `line` each): 0.24 ms a 1600x900 camera against 0.94 with a call per number and line."""
    import cv2

    height, width = canvas.shape
    low = np.tile(np.array([0, 0, height // 30], np.int64), RAIN_STREAKS)
    high = np.tile(np.array([width, height, height // 10], np.int64), RAIN_STREAKS)
    x, y, length = rng.integers(low, high).reshape(RAIN_STREAKS, 3).T
    starts = np.stack([x, y], axis=1)
    ends = np.stack([x + length // 6, y + length], axis=1)
    lines = list(np.stack([starts, ends], axis=1).astype(np.int32))  # (2, 2) each
    cv2.polylines(canvas, lines, False, 1.0, 1, cv2.LINE_AA)


def _sensor_effects(
    rgb: NDArray[np.uint8], conditions: Conditions, light: Lighting, seed: int
) -> NDArray[np.uint8]:
    """What the camera adds over a shaded image: noise in low light, streaks in rain."""
    rng = np.random.default_rng(seed)
    image = rgb
    if light.night:
        image = with_sensor_noise(contiguous_rgb(rgb), rng)  # saturating, in whole levels
    if conditions.weather == Weather.RAIN:
        image = _rain(contiguous_rgb(image), rng)
    return image


def reduced_sensor_effects(
    rgb: NDArray[np.uint8],
    conditions: Conditions,
    light: Lighting,
    seed: int,
    full_shape: tuple[int, int],
    gain: float = 1.0,
    noise_added: bool = False,
) -> NDArray[np.uint8]:
    """`_sensor_effects` for an image drawn smaller than the camera's `full_shape` (rows,
    columns), as the full image would show after an area reduction to `rgb`'s size: exposed by
    `gain`, then the same noise and the same streaks (the same draws of `seed`'s generator)
    made at the full size and averaged over each drawn pixel's area, then added and blended as
    there. What the full image clips at 0 or 255 before averaging is not clipped here: a
    difference below a level. `noise_added`: the night's noise is in `rgb` already (added by
    the GL renderer's reduction at `night_noise_start`, `with_reduced_noise`'s arithmetic);
    only the rain's streaks, from the same generator, are left."""
    import cv2

    night = light.night
    rain = conditions.weather == Weather.RAIN
    rgb = expose(rgb, gain)
    if not night and not rain:
        return rgb
    rng = np.random.default_rng(seed)
    size = (rgb.shape[1], rgb.shape[0])
    if night:
        start = noise_offset(math.prod((*full_shape, 3)), rng)
        if noise_added and start is None:
            raise ValueError(f"a {full_shape} camera draws its noise afresh: none was added")
        if not noise_added:
            rgb = with_reduced_noise(rgb, start, full_shape, rng)
    if not rain:
        return rgb
    image = contiguous_rgb(rgb).astype(np.float32)
    canvas = _streak_canvas(full_shape)
    try:
        _draw_streaks(canvas, rng)
        weight = cv2.resize(canvas, size, interpolation=cv2.INTER_AREA) * RAIN_OPACITY
    finally:
        canvas.fill(0.0)
    weight = weight[..., None]
    image = (image * (1.0 - weight) + np.float32(RAIN_RGB) * weight) / np.float32(
        1.0 + BLEND_EPSILON
    )
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def night_noise_start(seed: int, full_shape: tuple[int, int]) -> int | None:
    """Where the noise of a night camera of `full_shape` (rows, columns) with `seed` starts in
    the pool (`reduced_sensor_effects`' first draw); None where it is drawn afresh."""
    return noise_offset(math.prod((*full_shape, 3)), np.random.default_rng(seed))


def with_reduced_noise(
    rgb: NDArray[np.uint8],
    start: int | None,
    full_shape: tuple[int, int],
    rng: np.random.Generator | None = None,
) -> NDArray[np.uint8]:
    """`rgb` (H, W, 3) plus the night's noise made at `full_shape` (rows, columns: the pool's
    window from `start`, or drawn afresh from `rng` where `start` is None) and averaged over
    each pixel's area (OpenCV's INTER_AREA), clipped and rounded: a new image."""
    import cv2

    shape = (*full_shape, 3)
    if start is None:
        noise = _fresh_noise(shape, rng)
    else:
        noise = noise_pool()[start : start + math.prod(shape)].reshape(shape)
    size = (rgb.shape[1], rgb.shape[0])
    image = contiguous_rgb(rgb).astype(np.float32)
    image += cv2.resize(noise.astype(np.float32), size, interpolation=cv2.INTER_AREA)
    np.clip(image, 0.0, 255.0, out=image)
    return np.rint(image).astype(np.uint8)


# The shaders' look per weather and time of day. Colours are linear-ish RGB in [0, 1]; values
# were set by eye against photographs of streets under each condition, keeping a clear day's
# brightness near the plain Lambert shading that came before (ambient + diffuse about 1).
CLOUD_COVER = {Weather.CLEAR: 0.12, Weather.CLOUDY: 0.55, Weather.OVERCAST: 0.95,
               Weather.RAIN: 1.0, Weather.FOG: 1.0, Weather.WET: 0.45}  # fmt: skip
WETNESS = {Weather.RAIN: 1.0, Weather.WET: 0.7}
SUN_SHADOWS = (Weather.CLEAR, Weather.CLOUDY, Weather.WET)  # a visible sun casts shadows
DAY_ZENITH, DAY_HORIZON = (0.28, 0.47, 0.82), (0.74, 0.81, 0.90)
LOW_SUN_ZENITH, LOW_SUN_HORIZON = (0.33, 0.42, 0.66), (0.96, 0.72, 0.50)
GREY_SKY = {Weather.OVERCAST: (0.66, 0.68, 0.71), Weather.RAIN: (0.50, 0.52, 0.55),
            Weather.FOG: (0.78, 0.79, 0.80)}  # fmt: skip
NIGHT_ZENITH, NIGHT_HORIZON = (0.012, 0.016, 0.04), (0.09, 0.08, 0.085)  # city glow low down
NIGHT_AMBIENT = (0.045, 0.05, 0.07)
MOONLIGHT_RGB = (0.05, 0.055, 0.075)
STREET_LAMP_RGB = (1.0, 0.78, 0.48)  # high-pressure sodium and warm LED: orange-white
STREET_LAMP_REACH_M = 14.0
STREET_LAMP_GAIN = 1.25  # light on the ground right under a lamp, against the noon sun's ~0.6
LAMP_RASTER_M = 0.5  # the lamps' light varies over metres: a coarse raster is enough
HEADLIGHT_RGB = (1.1, 1.05, 0.95)
BEAM_REACH_M = 45.0  # the shader's headlight beams (the CPU path's cone: HEADLIGHT_REACH_M)
LAMPS_ON_BELOW_RAD = math.radians(3.0)  # street lamps switch on when the sun sinks below this
HEADLIGHTS_BELOW_RAD = math.radians(10.0)  # drivers turn headlights on at dusk


@dataclass(frozen=True)
class ShaderLook:
    """The GL renderer's uniforms for one clip's conditions (`sim/shaders/*.glsl`)."""

    light_direction: tuple[float, float, float]
    sun_rgb: tuple[float, float, float]
    sky_ambient: tuple[float, float, float]
    ground_ambient: tuple[float, float, float]
    zenith_rgb: tuple[float, float, float]
    horizon_rgb: tuple[float, float, float]
    cloud_cover: float
    cloud_rgb: tuple[float, float, float]
    sun_disc: float
    shadows: bool
    fog_rgb: tuple[float, float, float]
    fog_density: float  # per metre: 3 / visibility (contrast 5% at the visibility distance)
    wetness: float
    lamps_on: bool  # street lamps, lit windows, and the headlights' cones on the road
    headlights: bool  # vehicles' head and tail lamps glow (dusk, night, fog)
    lamp_rgb: tuple[float, float, float] = STREET_LAMP_RGB
    spot_rgb: tuple[float, float, float] = HEADLIGHT_RGB
    spot_reach_m: float = BEAM_REACH_M

    def plain(self) -> ShaderLook:
        """The same sun without weather or night: the top view's look (a map to read)."""
        day_sun = tuple(float(v) for v in np.maximum(self.sun_rgb, 0.45))
        return dataclasses.replace(self, fog_density=0.0, wetness=0.0, lamps_on=False, headlights=False,
                       sky_ambient=(0.6, 0.6, 0.62), ground_ambient=(0.45, 0.45, 0.45),
                       sun_rgb=day_sun)  # fmt: skip


def _scaled(rgb: tuple[float, float, float], factor: float) -> tuple[float, float, float]:
    return (rgb[0] * factor, rgb[1] * factor, rgb[2] * factor)


def shader_look(conditions: Conditions, origin: GeoOrigin) -> ShaderLook:
    """The shaders' sky, light and weather for `conditions` at `origin`."""
    light = lighting(conditions, origin)
    _, elevation = sun_position(conditions.start_time_utc, origin)
    weather = conditions.weather
    visibility = VISIBILITY_M[weather]
    fog_density = 0.0 if visibility is None else 3.0 / visibility
    wetness = WETNESS.get(weather, 0.0)
    grey = GREY_SKY.get(weather)
    cover = CLOUD_COVER[weather]
    if light.night:
        fog = tuple(float(v) for v in FOG_RGB / 255.0 * NIGHT_GAIN * 0.6)
        return ShaderLook(
            (0.3, 0.2, 0.93), MOONLIGHT_RGB, NIGHT_AMBIENT, _scaled(NIGHT_AMBIENT, 0.6),
            NIGHT_ZENITH, NIGHT_HORIZON, cover, (0.07, 0.07, 0.08), 0.0, False, fog,
            fog_density, wetness, True, True,
        )  # fmt: skip
    low_sun = elevation < math.radians(15)
    zenith, horizon = (LOW_SUN_ZENITH, LOW_SUN_HORIZON) if low_sun else (DAY_ZENITH, DAY_HORIZON)
    dim = float(np.clip((elevation + math.radians(4)) / math.radians(14), 0.25, 1.0))
    if grey is not None:
        zenith = horizon = _scaled(grey, dim)
    else:
        zenith, horizon = _scaled(zenith, dim), _scaled(horizon, dim)
    sun_rgb = _scaled(light.colour, light.diffuse * dim)
    ambient = light.ambient * dim
    sky_ambient = (ambient * 0.95, ambient * 1.0, ambient * 1.08)
    cloud_rgb = _scaled((0.92, 0.92, 0.94) if grey is None else grey, dim)
    fog = tuple(float(v) for v in FOG_RGB / 255.0 * dim)
    return ShaderLook(
        light.direction, sun_rgb, sky_ambient, _scaled(sky_ambient, 0.7), zenith, horizon, cover,
        cloud_rgb, 1.0 if grey is None else 0.0, weather in SUN_SHADOWS, fog, fog_density,
        wetness, elevation < LAMPS_ON_BELOW_RAD,
        elevation < HEADLIGHTS_BELOW_RAD or weather == Weather.FOG,
    )  # fmt: skip


@dataclass(frozen=True)
class LampRaster:
    """The street lamps' light on level ground per cell (cell (0, 0)'s corner at `origin_xy_m`,
    rows along y), in units of the lamp colour's intensity."""

    origin_xy_m: tuple[float, float]
    cell_m: float
    values: NDArray[np.float32]  # (rows, columns)


def lamp_raster(
    lamps_m: NDArray[np.float64], bounds_m: tuple[float, float, float, float]
) -> LampRaster:
    """Light on level ground from street lamps at `lamps_m` `(L, 3)`, over `bounds_m` (x0, y0,
    x1, y1) plus the lamps' reach: each lamp an inverse-square-like falloff (gain
    `STREET_LAMP_GAIN` under it, `STREET_LAMP_REACH_M` its scale) times the cosine of its light's
    angle to the ground, fading out between 1.5 and 2.5 reaches. Precomputed once, so the
    shader reads one texel for every lamp of the map instead of looping over a few."""
    reach = 2.5 * STREET_LAMP_REACH_M
    x0, y0, x1, y1 = bounds_m
    origin = np.array([x0 - reach, y0 - reach])
    columns = int(np.ceil((x1 - x0 + 2 * reach) / LAMP_RASTER_M))
    rows = int(np.ceil((y1 - y0 + 2 * reach) / LAMP_RASTER_M))
    xs = origin[0] + (np.arange(columns) + 0.5) * LAMP_RASTER_M
    ys = origin[1] + (np.arange(rows) + 0.5) * LAMP_RASTER_M
    values = np.zeros((rows, columns), np.float32)
    for x, y, height in np.asarray(lamps_m, dtype=np.float64).reshape(-1, 3):
        # only the window of cells the lamp reaches
        c0, c1 = np.searchsorted(xs, [x - reach, x + reach])
        r0, r1 = np.searchsorted(ys, [y - reach, y + reach])
        dx, dy = xs[c0:c1][None, :] - x, ys[r0:r1][:, None] - y
        distance = np.sqrt(dx * dx + dy * dy + height * height)
        falloff = STREET_LAMP_GAIN / (1.0 + 2.0 * (distance / STREET_LAMP_REACH_M) ** 2)
        fade = np.clip((reach - distance) / STREET_LAMP_REACH_M, 0.0, 1.0)
        values[r0:r1, c0:c1] += (falloff * fade * fade * (3 - 2 * fade) * height / distance).astype(
            np.float32
        )
    return LampRaster((float(origin[0]), float(origin[1])), LAMP_RASTER_M, values)


HEADLIGHT_GAIN = 3.0  # a headlight's light on the road near it, against the lamps' 1.25
HEADLIGHT_CONE_COS = (0.82, 0.95)  # the beam: full inside 18 degrees, none beyond 35


def headlight_raster(
    spots: Sequence[tuple[Sequence[float], Sequence[float]]],
    like: LampRaster,
    reach_m: float = BEAM_REACH_M,
) -> NDArray[np.float32]:
    """Light on level ground (z = 0) from headlights, on the cells of `like` (the lamps'
    raster), in units of the headlight colour's intensity. `spots`: (position, unit direction)
    of each, world frame. A beam lights a cell by the cone of its direction (a smoothstep
    between `HEADLIGHT_CONE_COS`), a falloff (1 - distance / `reach_m`)^2, and a wrapped cosine
    of the light's angle to the ground (beams are shaped to throw far along the road: the road,
    met at a grazing angle, is lit more than a cosine law from one point would give). Remade at
    every state, only over each beam's sector; the raster's edge cells stay dark (the texture
    clamps to them)."""
    values = np.zeros(like.values.shape, np.float32)
    add_headlights(values, spots, like, reach_m)
    return values


Box = tuple[int, int, int, int]  # rows and columns of a raster: r0, r1, c0, c1 (ends excluded)


def box_union(first: Box | None, second: Box | None) -> Box | None:
    """The smallest box holding both (None: no box)."""
    if first is None or second is None:
        return first if second is None else second
    return (min(first[0], second[0]), max(first[1], second[1]),
            min(first[2], second[2]), max(first[3], second[3]))  # fmt: skip


def add_headlights(
    values: NDArray[np.float32],
    spots: Sequence[tuple[Sequence[float], Sequence[float]]],
    like: LampRaster,
    reach_m: float = BEAM_REACH_M,
) -> Box | None:
    """`headlight_raster`'s light added into `values` (the raster's shape, float32; a view will
    do), beam by beam in the same order; the rows and columns it touched (r0, r1, c0, c1: a
    box holding every beam's sector), or None where no beam reached a cell."""
    rows, columns = like.values.shape
    x0, y0 = like.origin_xy_m
    cell = like.cell_m
    half_angle = math.acos(HEADLIGHT_CONE_COS[0])
    low, high = HEADLIGHT_CONE_COS
    box = None
    for position, direction in spots:
        px, py, pz = (float(v) for v in position)
        dx, dy, dz = (float(v) for v in direction)
        heading = math.atan2(dy, dx)
        # the beam's sector on the ground: the lamp and its reach at the heading and both edges
        ends = [(px, py)] + [
            (px + reach_m * math.cos(heading + a), py + reach_m * math.sin(heading + a))
            for a in (-half_angle, -0.5 * half_angle, 0.0, 0.5 * half_angle, half_angle)
        ]
        xs, ys = zip(*ends, strict=False)
        c0 = max(int((min(xs) - x0) / cell), 1)
        c1 = min(math.ceil((max(xs) - x0) / cell), columns - 1)
        r0 = max(int((min(ys) - y0) / cell), 1)
        r1 = min(math.ceil((max(ys) - y0) / cell), rows - 1)
        if c0 >= c1 or r0 >= r1:
            continue
        box = box_union(box, (r0, r1, c0, c1))
        gx = (px - (x0 + (np.arange(c0, c1) + 0.5) * cell))[None, :]  # cell to lamp
        gy = (py - (y0 + (np.arange(r0, r1) + 0.5) * cell))[:, None]
        squared = gx * gx + gy * gy + pz * pz
        distance = np.sqrt(squared)
        aim = -(gx * dx + gy * dy + pz * dz) / distance  # cosine off the beam
        t = np.clip((aim - low) / (high - low), 0.0, 1.0)
        cone = t * t * (3.0 - 2.0 * t)
        reach = np.clip(1.0 - distance / reach_m, 0.0, 1.0)
        facing = np.clip((pz / distance + 0.6) / 1.6, 0.0, 1.0)
        values[r0:r1, c0:c1] += (HEADLIGHT_GAIN * cone * reach * reach * facing).astype(np.float32)
    return box
