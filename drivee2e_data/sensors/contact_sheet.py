"""A contact sheet for a person to look at: six surround views from the ego and a top view."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.sensors import bev
from drivee2e_data.sensors.camera import render, with_conditions
from drivee2e_data.sensors.ego_state import ego_motion
from drivee2e_data.sensors.rig import default_rig
from drivee2e_data.sim.world import World

# the rig's cameras, in the order the sheet shows them (front row, back row)
SHEET_ORDER = (
    "CAM_FRONT_LEFT",
    "CAM_FRONT",
    "CAM_FRONT_RIGHT",
    "CAM_BACK_LEFT",
    "CAM_BACK",
    "CAM_BACK_RIGHT",
)
TILE = (480, 270)  # width, height of each surround view
# a label's outline: its glyphs drawn dark this many pixels around it (`outlined_text`)
OUTLINE_OFFSETS = tuple((dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy)
TOP_VIEW_HALF_WIDTH_M = 60.0


def surround(
    world: World, ego_to_world: NDArray[np.float64], frame: int = 0
) -> list[tuple[str, NDArray[np.uint8]]]:
    """The six views from the rig mounted at `ego_to_world` (rear axle), the clip's weather and
    light applied."""
    width, height = TILE  # the cameras' 16:9, smaller
    rig = default_rig()
    views = []
    for name in SHEET_ORDER:
        camera = replace(rig.camera(name), width=width, height=height)
        image = render(world, camera, ego_to_world, mask=False)
        rgb = with_conditions(world, image, frame)
        views.append((name, rgb))
    return views


def contact_sheet(world: World, frame: int) -> NDArray[np.uint8]:
    """(H, W, 3) RGB: the six views in two rows beside a square top view (ego heading up), each
    labelled."""
    ego = world.scenario.ego
    if ego is None:
        raise ValueError(f"scenario {world.scenario.scenario_id!r} has no ego; run drivee2e curate")
    ego_to_world = ego_motion(world.scenario).ego_to_world(frame)
    x, y = float(ego.x_m[frame]), float(ego.y_m[frame])
    world.place_ego(x, y, ego.track_id)
    world.set_time(frame)
    tiles = surround(world, ego_to_world, frame)
    world.place_ego(x, y, None)  # the top view shows the ego too
    world.set_time(frame)
    width, height = TILE
    top = bev.top_view(world, ego_to_world, 2 * height, TOP_VIEW_HALF_WIDTH_M)
    labelled = []
    for name, image in tiles:
        image = np.ascontiguousarray(image)
        outlined_text(image, name, (8, 22))
        labelled.append(image)
    rows = [np.concatenate(labelled[:3], axis=1), np.concatenate(labelled[3:], axis=1)]
    sheet = np.concatenate([np.concatenate(rows, axis=0), np.ascontiguousarray(top)], axis=1)
    caption = f"{world.scenario.scenario_id}  frame {frame}  renderer {world.renderer}"
    outlined_text(sheet, caption, (3 * width + 8, 22))
    return sheet


def outlined_text(
    image: NDArray[np.uint8], text: str, origin: tuple[int, int], scale: float = 0.6
) -> None:
    """White text with a dark outline, readable on sky and on road, drawn into `image` (RGB or
    BGR) with its baseline's left end at `origin` (x, y pixels). The outline is the same glyphs
    drawn dark one pixel around: OpenCV lays thick strokes out wider than thin ones (5.0: a
    38-character caption 323 against 303 pixels), so a thick dark pass under a thin white one
    drifts off it along the line."""
    import cv2

    x, y = origin
    for dx, dy in OUTLINE_OFFSETS:
        cv2.putText(image, text, (x + dx, y + dy), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1,
                    cv2.LINE_AA)  # fmt: skip
    cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1,
                cv2.LINE_AA)  # fmt: skip
