"""Milliseconds per camera image for the weather and light post-processing, per weather by day
and at night, against the reference in the same run: the same code with the sensor noise drawn
afresh, the fog colour image filled for every image and the wet ground darkened through numpy's
masked copy (as it was before 2026-11-23).

    python scripts/dev/bench_post_process.py [--repeats 10] [--size 1024x768]

The image is random RGB with random depth (1-200 m) at the size the EGL renderer draws a
1600x900 camera (the weather is applied before resizing); the front camera's headlights are on.
"""

from __future__ import annotations

import argparse
import statistics
import time
from datetime import datetime, timezone
from unittest import mock

import numpy as np

from drivee2e_data.scenario import Conditions, TimeOfDay, Weather
from drivee2e_data.sim import conditions
from drivee2e_data.sim.conditions import Lighting, post_process


def fresh_noise(shape: tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
    return rng.standard_normal(shape, dtype=np.float32)


def filled_image(shape: tuple[int, ...], rgb: tuple[int, int, int]) -> np.ndarray:
    image = np.empty(shape, np.uint8)
    image[:] = rgb
    return image


def numpy_darken(image: np.ndarray, where: np.ndarray) -> None:
    import cv2

    darker = cv2.convertScaleAbs(image, alpha=conditions.WET_DARKENING)
    np.copyto(image, darker, where=where[..., None])


def milliseconds(rgb, depth, weather: Weather, night: bool, repeats: int) -> float:
    light = Lighting((0.0, 0.0, 1.0), (1.0, 1.0, 1.0), 0.5, 0.5, night)
    when = datetime(2026, 5, 1, tzinfo=timezone.utc)
    time_of_day = TimeOfDay.NIGHT if night else TimeOfDay.NOON
    scene = Conditions(weather, time_of_day, when)
    post_process(rgb, depth, scene, light, seed=0, headlights=True)  # warm-up (noise pool)
    times = []
    for seed in range(repeats):
        start = time.perf_counter()
        post_process(rgb, depth, scene, light, seed=seed, headlights=True)
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--size", default="1024x768")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    depth = rng.uniform(1.0, 200.0, (height, width)).astype(np.float32)
    print(f"{width}x{height}, median of {args.repeats}; ms per image")
    print(f"{'weather':10} {'light':6} {'reference':>10} {'ours':>8} {'ratio':>7}")
    for weather in (Weather.CLEAR, Weather.OVERCAST, Weather.FOG, Weather.RAIN):
        for night in (False, True):
            with (
                mock.patch.object(conditions, "sensor_noise", fresh_noise),
                mock.patch.object(conditions, "_uniform_image", filled_image),
                mock.patch.object(conditions, "_darken", numpy_darken),
            ):
                reference = milliseconds(rgb, depth, weather, night, args.repeats)
            ours = milliseconds(rgb, depth, weather, night, args.repeats)
            light = "night" if night else "day"
            ratio = reference / ours if ours > 0.01 else float("nan")
            print(f"{weather.value:10} {light:6} {reference:10.1f} {ours:8.1f} {ratio:6.2f}x")


if __name__ == "__main__":
    main()
