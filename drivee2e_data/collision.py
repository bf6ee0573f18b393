"""One definition of a collision, shared by the synthetic source's staging, the closed-loop rules
(`metrics/closedloop.py`) and the expert-replay check of curation (`evaluate/expert_check.py`),
so that a clip staged clean is clean by the rules its expert is scored by.

Two agents collide at a 10 Hz step when their boxes overlap at that step: each box is the
agent's length and width about its centre, turned by its yaw, in the world frame (metres,
radians); touching counts as apart. The closed-loop ego's box is its logged size about the
kinematic bicycle's centre (`sim/vehicle.py`).

Staging asks for more than the rules: the ego's box grown by `EXPERT_TRACKING_MARGIN_M` on every
side must touch no other box, since the closed-loop expert drives its logged path through the
harness's controllers and strays from it by up to that much.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.geometry import box_corners_2d, boxes_overlap

# The log-replay expert strays at most 0.55 m from its logged path on the canonical synthetic
# set's U-turns and turns (pure pursuit, docs/closedloop.md); staging keeps this much clear
# around the ego so that no such stray turns a near miss into a collision
EXPERT_TRACKING_MARGIN_M = 0.6


def boxes_collide(
    centre_a_m: NDArray[np.float64],
    yaw_a_rad: NDArray[np.float64],
    size_a_m: NDArray[np.float64],
    centre_b_m: NDArray[np.float64],
    yaw_b_rad: NDArray[np.float64],
    size_b_m: NDArray[np.float64],
    margin_a_m: float | NDArray[np.float64] = 0.0,
) -> NDArray[np.bool_]:
    """Whether box a, grown by `margin_a_m` (m, a number or `(...)`) on every side, overlaps box
    b, pair by pair (arrays broadcast against each other).

    `centre_*_m: (..., 2)` world positions; `yaw_*_rad: (...)`; `size_*_m: (..., 2)` length and
    width. Returns `(...)` booleans."""
    size_a = np.asarray(size_a_m, np.float64)
    size_b = np.asarray(size_b_m, np.float64)
    margin = np.asarray(margin_a_m, np.float64)
    corners_a = box_corners_2d(
        np.asarray(centre_a_m, np.float64),
        np.asarray(yaw_a_rad, np.float64),
        size_a[..., 0] + 2.0 * margin,
        size_a[..., 1] + 2.0 * margin,
    )
    corners_b = box_corners_2d(
        np.asarray(centre_b_m, np.float64),
        np.asarray(yaw_b_rad, np.float64),
        size_b[..., 0],
        size_b[..., 1],
    )
    return boxes_overlap(corners_a, corners_b)
