"""An episode as a short video (`evaluate --record mp4`): at each 10 Hz step the front camera as
the ego saw it beside the top view, with the logged path (white), the path driven so far
(green), the agent's planned waypoints (yellow) and the ego's box drawn over it; MPEG-4 Part 2
(`mp4v`, what OpenCV's wheels write), a few MB a clip. The scene is posed again from the
episode's trace after it ends, with the collection's own camera, weather and top view."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.evaluate.episode import STEP_S, EpisodeResult
from drivee2e_data.geometry import box_corners_2d, to_world_frame
from drivee2e_data.scenario import Scenario
from drivee2e_data.sensors import bev
from drivee2e_data.sensors.camera import NO_DEPTH, render, with_conditions
from drivee2e_data.sensors.ego_state import se3, to_ego_frame
from drivee2e_data.sensors.suite import SuiteOptions, configured_rig
from drivee2e_data.sim.gl_readback import contiguous_rgb
from drivee2e_data.sim.vehicle import Bicycle, VehicleState
from drivee2e_data.sim.world import World

FRONT_SIZE = (640, 360)  # the front camera, 1600 x 900 at 0.4
TOP_PX = 360
TOP_HALF_WIDTH_M = 40.0
FPS = round(1.0 / STEP_S)
LOGGED_BGR, DRIVEN_BGR, PLANNED_BGR = (235, 235, 235), (80, 230, 25), (0, 220, 255)


def top_view_pixels(
    xy_m: NDArray[np.float64], ego_x_m: float, ego_y_m: float, ego_yaw_rad: float
) -> NDArray[np.int32]:
    """World points `(N, 2)` as pixels `(N, 2)` (column, row) of the top view centred on the
    ego, its heading up (`sensors.bev`)."""
    ego = to_ego_frame(np.asarray(xy_m, np.float64).reshape(-1, 2), ego_x_m, ego_y_m, ego_yaw_rad)
    scale = TOP_PX / (2.0 * TOP_HALF_WIDTH_M)
    columns = TOP_PX / 2 - ego[:, 1] * scale
    rows = TOP_PX / 2 - ego[:, 0] * scale
    return np.round(np.column_stack([columns, rows])).astype(np.int32)


def write_video(
    path: Path,
    world: World,
    scenario: Scenario,
    result: EpisodeResult,
    logged_xy_m: NDArray[np.float64],
    ground_z_m: NDArray[np.float64],
    bicycle: Bicycle,
) -> None:
    """Write `result.trace` (the episode must keep its trace) to `path`, atomically.
    `ground_z_m`: the logged ground height per frame (the ego's z)."""
    import cv2

    camera = configured_rig(SuiteOptions(cameras=("CAM_FRONT",), image_size=FRONT_SIZE)).cameras[0]
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial.mp4")
    size = (FRONT_SIZE[0] + TOP_PX, FRONT_SIZE[1])
    writer = cv2.VideoWriter(str(partial), cv2.VideoWriter_fourcc(*"mp4v"), FPS, size)
    if not writer.isOpened():
        raise OSError(f"{path}: OpenCV cannot write mp4v video here")
    last = scenario.num_frames - 1
    driven: list[NDArray[np.float64]] = []
    try:
        for record in result.trace:
            state, frame = record.state, min(record.step, last)
            driven.append(state.xy_m)
            signals = {s.signal_id: s.state_at(frame) for s in scenario.signals}
            centre = bicycle.centre_xy_m(state)  # headlights and shadow at the box, as logged
            world.place_ego(float(centre[0]), float(centre[1]), world.ego_id, state.yaw_rad)
            placements = {p.track_id: (p.x_m, p.y_m, p.z_m, p.yaw_rad) for p in record.agents}
            world.show(placements, signals, frame)
            ego_to_world = se3(state.x_m, state.y_m, float(ground_z_m[frame]), state.yaw_rad)
            view = render(world, camera, ego_to_world, mask=False, depth_at=NO_DEPTH)
            front = with_conditions(world, view, frame)
            top = contiguous_rgb(bev.top_view(world, ego_to_world, TOP_PX, TOP_HALF_WIDTH_M))
            canvas = np.concatenate([cv2.resize(front, FRONT_SIZE), top], axis=1)
            image = np.ascontiguousarray(canvas[..., ::-1])  # OpenCV writes BGR
            _draw_top(image, state, np.array(driven), logged_xy_m, record.planned_xy_m, bicycle)
            text = f"{record.step * STEP_S:5.1f} s  {state.speed_mps * 3.6:5.1f} km/h"
            cv2.putText(image, text, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2)
            writer.write(image)
    finally:
        writer.release()
    partial.replace(path)


def _draw_top(
    image: NDArray[np.uint8],
    state: VehicleState,
    driven_xy_m: NDArray[np.float64],
    logged_xy_m: NDArray[np.float64],
    planned_ego_m: NDArray[np.float64] | None,
    bicycle: Bicycle,
) -> None:
    """The paths, the plan and the ego's box over the top view (the image's right part)."""
    import cv2

    top = image[:, FRONT_SIZE[0] :]
    pose = (state.x_m, state.y_m, state.yaw_rad)
    for points, colour in ((logged_xy_m, LOGGED_BGR), (driven_xy_m, DRIVEN_BGR)):
        if len(points) >= 2:
            cv2.polylines(top, [top_view_pixels(points, *pose)], False, colour, 2, cv2.LINE_AA)
    if planned_ego_m is not None and len(planned_ego_m):
        world = to_world_frame(planned_ego_m, state.xy_m, state.yaw_rad)
        for column, row in top_view_pixels(world, *pose):
            cv2.circle(top, (int(column), int(row)), 3, PLANNED_BGR, -1, cv2.LINE_AA)
    box = box_corners_2d(
        bicycle.centre_xy_m(state), state.yaw_rad, bicycle.length_m, bicycle.width_m
    )
    cv2.polylines(top, [top_view_pixels(box, *pose)], True, DRIVEN_BGR, 2, cv2.LINE_AA)
