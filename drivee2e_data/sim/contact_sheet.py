"""A contact sheet for a person to look at: six surround views from the ego and a top view."""

from __future__ import annotations

import zlib

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.sensors.rig import default_rig
from drivee2e_data.sim.conditions import post_process
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
TOP_VIEW_HALF_WIDTH_M = 60.0


def surround(
    world: World, ego_xy_m: NDArray, ego_yaw_rad: float, frame: int = 0
) -> list[tuple[str, NDArray[np.uint8]]]:
    """The six views with the clip's weather and light applied."""
    width, height = TILE  # the cameras' 16:9, smaller
    rig = default_rig()
    c, s_ = np.cos(ego_yaw_rad), np.sin(ego_yaw_rad)
    ego_rotation = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    views = []
    for name in SHEET_ORDER:
        camera = rig.camera(name)
        eye = np.array([ego_xy_m[0], ego_xy_m[1], 0.0]) + ego_rotation @ camera.sensor_to_ego[:3, 3]
        target = eye + 10.0 * (ego_rotation @ camera.sensor_to_ego[:3, 2])
        image = world.render(eye, target, width, height, camera.vertical_fov_deg)
        seed = zlib.crc32(f"{world.scenario.scenario_id}/{frame}/{name}".encode())
        rgb = post_process(image.rgb, image.depth_m, world.scenario.conditions, world.lighting, seed,
                           headlights=name == "CAM_FRONT")  # fmt: skip
        views.append((name, rgb))
    return views


def top_view(world: World, centre_xy_m: NDArray, size_px: int) -> NDArray[np.uint8]:
    altitude = 150.0
    fov = float(np.rad2deg(2 * np.arctan(TOP_VIEW_HALF_WIDTH_M / altitude)))
    eye = np.array([centre_xy_m[0], centre_xy_m[1], altitude])
    target = np.array([centre_xy_m[0], centre_xy_m[1] + 1e-3, 0.0])
    # a near plane close to the ground keeps depth precise enough for paint 5 mm above the road
    return world.render(
        eye, target, size_px, size_px, fov, far_m=altitude + 20.0, near_m=altitude - 60.0
    ).rgb


def contact_sheet(world: World, frame: int) -> NDArray[np.uint8]:
    """(H, W, 3) RGB: the six views in two rows beside a square top view, each labelled."""

    ego = world.scenario.ego
    if ego is None:
        raise ValueError(f"scenario {world.scenario.scenario_id!r} has no ego; run drivee2e curate")
    xy = ego.xy_m[frame]
    world.place_ego(float(xy[0]), float(xy[1]), ego.track_id)
    world.set_time(frame)
    tiles = surround(world, xy, float(ego.yaw_rad[frame]), frame)
    world.place_ego(float(xy[0]), float(xy[1]), None)  # the top view shows the ego too
    world.set_time(frame)
    width, height = TILE
    top = top_view(world, xy, 2 * height)
    labelled = []
    for name, image in tiles:
        image = np.ascontiguousarray(image)
        _label(image, name, (8, 22))
        labelled.append(image)
    rows = [np.concatenate(labelled[:3], axis=1), np.concatenate(labelled[3:], axis=1)]
    sheet = np.concatenate([np.concatenate(rows, axis=0), np.ascontiguousarray(top)], axis=1)
    caption = f"{world.scenario.scenario_id}  frame {frame}  renderer {world.renderer}"
    _label(sheet, caption, (3 * width + 8, 22))
    return sheet


def _label(image: NDArray[np.uint8], text: str, origin: tuple[int, int]) -> None:
    """White text with a dark outline, readable on sky and on road."""
    import cv2

    for colour, thickness in (((0, 0, 0), 4), ((255, 255, 255), 1)):
        cv2.putText(
            image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, thickness, cv2.LINE_AA
        )
