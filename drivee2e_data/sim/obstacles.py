"""Models of the static obstacles a source gives as boxes (nuScenes' cones and barriers,
Argoverse 2's bollards, cones, barrels and signs): each a few coloured parts that fill the
obstacle's box, as triangles in the world frame; a kind without a model stays its box.

A pure function of the obstacle (no GL, no pybullet): the twin adds each part as static
geometry of kind "obstacle", drawn by the cameras and hit by the LiDAR's rays alike, so the
labels (semantic masks, depth, visibility) come from the same surfaces.
"""

from __future__ import annotations

import zlib

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.hdmap import StaticObstacle
from drivee2e_data.sim.models.mesh import box, loft, loft_caps, rotation_z

ORANGE_RGBA = (1.0, 0.45, 0.0, 1.0)  # traffic cones' and barrels' plastic
# a kind without a model (a parked bicycle, a stroller, a trailer): its box in a neutral grey
# (every obstacle's box was orange before they had models, which read as roadworks)
UNMODELLED_RGBA = (0.3, 0.3, 0.32, 1.0)
REFLECTIVE_RGBA = (0.93, 0.93, 0.9, 1.0)
BLACK_RGBA = (0.07, 0.07, 0.07, 1.0)
BOLLARD_RGBA = (0.85, 0.68, 0.08, 1.0)  # safety yellow steel
SIGN_POST_RGBA = (0.55, 0.56, 0.57, 1.0)
SIGN_RGBAS = {"stop_sign": (0.75, 0.08, 0.08, 1.0), "sign": (0.9, 0.9, 0.88, 1.0)}
# plastic water-filled barriers come in alternating colours, one per unit
BARRIER_RGBAS = ((0.9, 0.3, 0.05, 1.0), (0.92, 0.92, 0.9, 1.0))
SIDES = 10  # of a round part: obstacles are small in an image (a scene may hold a hundred)

Parts = list[tuple[tuple[float, ...], NDArray[np.float64]]]


def obstacle_parts(obstacle: StaticObstacle) -> Parts:
    """(rgba, triangles `(T, 3, 3)` counter-clockwise seen from outside) of `obstacle`'s model,
    inside its box (centred on `position_m`, turned `yaw_rad`); its plain box for a kind
    without a model."""
    length, width, height = (float(v) for v in obstacle.size_m)
    kind = obstacle.kind
    if kind in ("cone", "construction_cone"):
        parts = _cone(length, width, height)
    elif kind == "construction_barrel":
        parts = _banded_post(length, width, height, ORANGE_RGBA, (0.2, 0.35, 0.55, 0.7))
    elif kind == "bollard":
        parts = _banded_post(length, width, height, BOLLARD_RGBA, (0.72, 0.84))
    elif kind == "barrier":
        colour = BARRIER_RGBAS[zlib.crc32(obstacle.obstacle_id.encode()) % len(BARRIER_RGBAS)]
        parts = _barrier(length, width, height, colour)
    elif kind in SIGN_RGBAS:
        parts = _sign(length, width, height, SIGN_RGBAS[kind])
    else:
        parts = [(UNMODELLED_RGBA, box((0.0, 0.0, 0.0), (length, width, height)))]
    rotation = rotation_z(obstacle.yaw_rad)
    centre = np.asarray(obstacle.position_m, dtype=np.float64)
    return [(rgba, triangles @ rotation.T + centre) for rgba, triangles in parts]


def _round(
    heights: NDArray, scales: NDArray, half_xy: tuple[float, float], bottom: float,
    caps: tuple[bool, bool],
) -> NDArray[np.float64]:  # fmt: skip
    """A round part about the box's vertical axis: rings at `heights` above `bottom`, each an
    ellipse of half-axes `half_xy` times its scale (triangles in the box frame, centred), closed
    at its lower and upper end where `caps` says."""
    angles = np.linspace(0.0, 2 * np.pi, SIDES, endpoint=False)
    unit = np.column_stack([np.cos(angles) * half_xy[0], np.sin(angles) * half_xy[1]])
    rings = np.asarray(scales, dtype=np.float64)[:, None, None] * unit[None]
    sections = bottom + np.asarray(heights, dtype=np.float64)
    parts = [loft(sections, rings).reshape(-1, 3, 3)]
    ends = loft_caps(sections, rings)  # the lower end's fan, then the upper's
    parts += [ends[k * SIDES : (k + 1) * SIDES] for k in (0, 1) if caps[k]]
    # the loft runs along x with its rings in (y, z): turn x into z (a cyclic permutation of
    # the axes keeps the winding)
    return np.concatenate(parts)[..., [1, 2, 0]]


def _bands(
    height: float, bottom: float, half_xy: tuple[float, float], scale_at,
    marks: tuple[float, ...], body: tuple, band: tuple,
) -> Parts:  # fmt: skip
    """A round body from `bottom` up `height` (its section `half_xy` times `scale_at(z)`), split
    at `marks` (fractions of the height, pairs: a reflective band between each pair) into parts
    of its colour and the band's."""
    edges = [0.0, *marks, 1.0]
    parts: Parts = []
    for k in range(len(edges) - 1):
        low, high = edges[k] * height, edges[k + 1] * height
        heights = np.array([low, high])
        # the body closed as a whole: its ends capped, not the joints between its parts
        caps = (k == 0, k == len(edges) - 2)
        triangles = _round(heights, scale_at(heights), half_xy, bottom, caps)
        parts.append((band if k % 2 else body, triangles))
    return parts


def _cone(length: float, width: float, height: float) -> Parts:
    """A traffic cone: a black square foot the box's footprint wide, an orange cone on it with
    two white bands."""
    foot = min(0.05, 0.1 * height)

    def scale_at(z: NDArray) -> NDArray:  # 0.84 of the foot at the bottom, a tenth at the tip
        return 0.84 + (0.1 - 0.84) * z / (height - foot)

    parts: Parts = [(BLACK_RGBA, box((0.0, 0.0, -0.5 * height + 0.5 * foot),
                                     (length, width, foot)))]  # fmt: skip
    body = _bands(height - foot, -0.5 * height + foot, (0.5 * length, 0.5 * width), scale_at,
                  (0.38, 0.52, 0.64, 0.76), ORANGE_RGBA, REFLECTIVE_RGBA)  # fmt: skip
    return parts + body


def _banded_post(length: float, width: float, height: float, colour: tuple,
                 marks: tuple[float, ...]) -> Parts:  # fmt: skip
    """A round post or barrel filling its box, of `colour`, with reflective bands at `marks`."""
    return _bands(height, -0.5 * height, (0.5 * length, 0.5 * width),
                  lambda z: np.ones(len(z)), marks, colour, REFLECTIVE_RGBA)  # fmt: skip


def _barrier(length: float, width: float, height: float, colour: tuple) -> Parts:
    """A road barrier: a sloped-sided wall along the box's longer side, its foot as wide as
    the shorter side, its top a third of that (a jersey barrier's profile)."""
    along_x = length >= width
    run, thick = (length, width) if along_x else (width, length)
    half, top = 0.5 * thick, 0.17 * thick
    bottom = -0.5 * height
    # the profile across the wall, (across, up), counter-clockwise
    profile = np.array([
        [-half, bottom], [half, bottom], [half, bottom + 0.12 * height],
        [top, bottom + 0.75 * height], [top, bottom + height], [-top, bottom + height],
        [-top, bottom + 0.75 * height], [-half, bottom + 0.12 * height],
    ])  # fmt: skip
    sections = np.array([-0.5 * run, 0.5 * run])
    rings = np.broadcast_to(profile, (2, *profile.shape))
    triangles = np.concatenate([loft(sections, rings).reshape(-1, 3, 3),
                                loft_caps(sections, rings)])  # fmt: skip
    if not along_x:  # along y: turn the wall a quarter about z
        triangles = triangles @ rotation_z(0.5 * np.pi).T
    return [(colour, triangles)]


def _sign(length: float, width: float, height: float, colour: tuple) -> Parts:
    """A sign: a thin post, and a plate across the box's longer side on its upper third."""
    plate_height = 0.35 * height
    post_height = height - plate_height
    post = box((0.0, 0.0, -0.5 * height + 0.5 * post_height), (0.06, 0.06, post_height))
    size = (0.03, width, plate_height) if width >= length else (length, 0.03, plate_height)
    plate = box((0.0, 0.0, 0.5 * height - 0.5 * plate_height), size)
    return [(SIGN_POST_RGBA, post), (colour, plate)]
