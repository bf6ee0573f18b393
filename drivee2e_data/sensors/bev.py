"""The top view: a square image looking straight down on the ego, its heading up."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.sim.world import World

ALTITUDE_M = 150.0
DEFAULT_SIZE_PX = 400
DEFAULT_HALF_WIDTH_M = 50.0


def top_view(
    world: World,
    ego_to_world: NDArray[np.float64],
    size_px: int = DEFAULT_SIZE_PX,
    half_width_m: float = DEFAULT_HALF_WIDTH_M,
    casters_drawn: bool = False,
) -> NDArray[np.uint8]:
    """(size, size, 3) RGB centred on the ego, ego +x pointing up the image, ego +y left;
    `casters_drawn` as in `World.render` (the ego of a camera frame's state drawn)."""
    centre = ego_to_world[:3, 3]
    fov = float(np.rad2deg(2 * np.arctan(half_width_m / ALTITUDE_M)))
    eye = np.array([centre[0], centre[1], ALTITUDE_M])
    target = np.array([centre[0], centre[1], 0.0])
    # a near plane close to the ground keeps depth precise enough for paint 5 mm above the road
    return world.render(
        eye,
        target,
        size_px,
        size_px,
        fov,
        far_m=ALTITUDE_M + 20.0,
        near_m=ALTITUDE_M - 60.0,
        up=ego_to_world[:3, 0],
        look="plain",
        casters_drawn=casters_drawn,
    ).rgb
