"""Colours of the procedural models, drawn per instance from a seed (the track id's hash), so a
clip always looks the same."""

from __future__ import annotations

import zlib

import numpy as np

# Car body colours and their shares: the order of magnitude of the global colour-popularity
# surveys paint makers publish each year (white about a third, then black, grey and silver
# together about 45%, blue and red most of the rest)
CAR_COLOURS: tuple[tuple[str, tuple[float, float, float], float], ...] = (
    ("white", (0.88, 0.88, 0.87), 0.35),
    ("black", (0.05, 0.05, 0.06), 0.19),
    ("grey", (0.36, 0.37, 0.39), 0.17),
    ("silver", (0.64, 0.65, 0.67), 0.09),
    ("blue", (0.10, 0.20, 0.45), 0.08),
    ("red", (0.55, 0.05, 0.05), 0.07),
    ("beige", (0.60, 0.52, 0.40), 0.03),
    ("green", (0.10, 0.28, 0.16), 0.01),
    ("yellow", (0.85, 0.65, 0.05), 0.01),
)
# Fleets: buses and trucks come in livery colours, vans mostly white
BUS_COLOURS = ((0.80, 0.15, 0.12), (0.15, 0.45, 0.25), (0.90, 0.90, 0.88), (0.20, 0.35, 0.65),
               (0.95, 0.70, 0.10))  # fmt: skip
CARGO_COLOURS = ((0.92, 0.92, 0.90), (0.75, 0.76, 0.78), (0.15, 0.30, 0.55), (0.85, 0.45, 0.10))
# Clothing: dark and muted colours dominate what people wear in the street
CLOTHING = ((0.10, 0.10, 0.12), (0.22, 0.24, 0.30), (0.35, 0.35, 0.36), (0.15, 0.20, 0.35),
            (0.55, 0.50, 0.42), (0.80, 0.80, 0.78), (0.45, 0.12, 0.10), (0.20, 0.32, 0.22),
            (0.62, 0.45, 0.25), (0.70, 0.20, 0.30))  # fmt: skip
TROUSERS = ((0.12, 0.14, 0.22), (0.08, 0.08, 0.09), (0.30, 0.30, 0.32), (0.45, 0.40, 0.32),
            (0.20, 0.28, 0.45))  # fmt: skip
SKIN = ((0.93, 0.78, 0.65), (0.85, 0.66, 0.52), (0.72, 0.53, 0.39), (0.55, 0.38, 0.26),
        (0.38, 0.26, 0.18))  # fmt: skip
HAIR = ((0.08, 0.06, 0.05), (0.25, 0.16, 0.09), (0.45, 0.32, 0.18), (0.55, 0.55, 0.55),
        (0.70, 0.58, 0.35))  # fmt: skip
GLASS_RGB = (0.10, 0.13, 0.16)
TRIM_RGB = (0.08, 0.08, 0.09)  # bumpers, grilles, sills: black plastic
TYRE_RGB = (0.05, 0.05, 0.05)
RIM_RGB = (0.70, 0.71, 0.73)
SPOKE_RGB = (0.25, 0.25, 0.27)
HEADLIGHT_RGB = (1.0, 0.97, 0.88)
TAIL_RGB = (0.95, 0.06, 0.04)
FRAME_RGB = (0.15, 0.15, 0.16)  # bicycle and motorcycle frames
JITTER = 0.04  # each instance's colour varies this much per channel


def instance_rng(instance: str) -> np.random.Generator:
    """The random stream of one instance (a track id): the same in every process."""
    return np.random.default_rng(zlib.crc32(instance.encode()))


def car_colour(rng: np.random.Generator) -> tuple[float, float, float]:
    """A body colour drawn from `CAR_COLOURS`' shares, with a small jitter."""
    shares = np.array([share for _, _, share in CAR_COLOURS])
    index = int(rng.choice(len(CAR_COLOURS), p=shares / shares.sum()))
    return jittered(CAR_COLOURS[index][1], rng)


def pick(options: tuple[tuple[float, float, float], ...], rng: np.random.Generator):
    """One of `options`, jittered."""
    return jittered(options[int(rng.integers(len(options)))], rng)


def jittered(
    rgb: tuple[float, float, float], rng: np.random.Generator
) -> tuple[float, float, float]:
    values = np.clip(np.asarray(rgb) + rng.uniform(-JITTER, JITTER, 3), 0.0, 1.0)
    return (float(values[0]), float(values[1]), float(values[2]))
