"""Draw one frame of a collected log from the log alone: the six cameras with every annotated
box projected through the logged calibration (green: seen, grey: not seen by any camera), the
LiDAR sweep from above coloured by intensity with the boxes, and the logged top view.

    python scripts/plot_log_frame.py DATA/logs/<scenario_id>.mcap --frame 30 --out frame.png

Uses only the log (calibrations from its `drivee2e.rig` metadata): a check that images, boxes,
points and transforms agree.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from drivee2e_data.logs import topics
from drivee2e_data.logs.messages import LIDAR_DTYPE
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.sensors.camera import NEAR_M  # edges are cut where the cameras' views begin
from drivee2e_data.sensors.contact_sheet import SHEET_ORDER, outlined_text

TILE = (640, 360)
LIDAR_HALF_M, LIDAR_PX = 50.0, 720
EDGES = [
    (0, 1),
    (1, 2),
    (2, 3),
    (3, 0),
    (4, 5),
    (5, 6),
    (6, 7),
    (7, 4),
    (0, 4),
    (1, 5),
    (2, 6),
    (3, 7),
]


def box_corners_ego(box) -> NDArray[np.float64]:  # type: ignore[no-untyped-def]
    """(8, 3) corners of an annotated box in the ego frame, bottom face first."""
    half = np.array([box.length, box.width]) / 2
    c, s = np.cos(box.ego_yaw), np.sin(box.ego_yaw)
    corners = []
    for dz in (-box.height / 2, box.height / 2):
        for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
            x, y = sx * half[0], sy * half[1]
            corners.append([box.ego_x + c * x - s * y, box.ego_y + s * x + c * y, box.ego_z + dz])
    return np.array(corners)


def visible_edge(
    start: NDArray[np.float64], end: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """The part of the edge from `start` to `end` (camera frame, z forward) at least `NEAR_M`
    in front of the camera, or None where it all lies nearer or behind: a box beside the ego
    has corners behind a side camera and its near edges still cross the image."""
    if start[2] < NEAR_M and end[2] < NEAR_M:
        return None
    if start[2] >= NEAR_M and end[2] >= NEAR_M:
        return start, end
    crossing = start + (NEAR_M - start[2]) / (end[2] - start[2]) * (end - start)
    return (crossing, end) if start[2] < NEAR_M else (start, crossing)


def draw_camera(image: NDArray[np.uint8], calibration: dict, boxes: list) -> NDArray[np.uint8]:
    ego_to_camera = np.linalg.inv(np.array(calibration["sensor_to_ego"]))
    intrinsic = np.array(calibration["intrinsic"])
    for box in boxes:
        corners = box_corners_ego(box)
        camera = (ego_to_camera[:3, :3] @ corners.T).T + ego_to_camera[:3, 3]
        colour = (60, 220, 60) if box.cameras else (150, 150, 150)
        for a, b in EDGES:
            edge = visible_edge(camera[a], camera[b])
            if edge is None:
                continue
            ends = [intrinsic @ point for point in edge]
            first, second = (tuple(np.round(p[:2] / p[2]).astype(int)) for p in ends)
            cv2.line(image, first, second, colour, 2, cv2.LINE_AA)
    return image


def draw_lidar(
    points: NDArray, lidar_to_ego: NDArray[np.float64], boxes: list
) -> NDArray[np.uint8]:
    canvas = np.full((LIDAR_PX, LIDAR_PX, 3), 20, np.uint8)
    xyz = np.stack([points["x"], points["y"], points["z"]], -1).astype(np.float64)
    ego = xyz @ lidar_to_ego[:3, :3].T + lidar_to_ego[:3, 3]
    scale = LIDAR_PX / (2 * LIDAR_HALF_M)

    def to_pixels(xy: NDArray[np.float64]) -> NDArray[np.int64]:
        # ego +x up the image, +y to the left
        return np.stack(
            [LIDAR_PX / 2 - xy[:, 1] * scale, LIDAR_PX / 2 - xy[:, 0] * scale], -1
        ).astype(int)

    pixels = to_pixels(ego[:, :2])
    inside = (pixels >= 0).all(1) & (pixels < LIDAR_PX).all(1)
    shade = (90 + 165 * points["intensity"][inside]).astype(np.uint8)
    colours = cv2.applyColorMap(shade[:, None], cv2.COLORMAP_VIRIDIS)[:, 0]
    canvas[pixels[inside, 1], pixels[inside, 0]] = colours
    for box in boxes:
        footprint = to_pixels(box_corners_ego(box)[:4, :2])
        colour = (60, 220, 60) if box.num_lidar_points else (150, 150, 150)
        cv2.polylines(
            canvas, [footprint.reshape(-1, 1, 2).astype(np.int32)], True, colour, 1, cv2.LINE_AA
        )
    cv2.rectangle(
        canvas,
        (LIDAR_PX // 2 - 4, LIDAR_PX // 2 - 9),
        (LIDAR_PX // 2 + 4, LIDAR_PX // 2 + 9),
        (60, 60, 255),
        -1,
    )
    return canvas


def label(image: NDArray[np.uint8], text: str) -> None:
    outlined_text(image, text, (8, 24), 0.65)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("log", type=Path)
    parser.add_argument("--frame", type=int, default=0)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    with LogReader(args.log) as log:
        messages = log.frame(args.frame)
        rig, scenario_id = log.rig, log.scenario_id
    boxes = list(messages[topics.OBJECTS].objects)
    tiles = []
    for name in SHEET_ORDER:
        data = np.frombuffer(messages[topics.image_topic(name)].data, np.uint8)
        image = draw_camera(cv2.imdecode(data, cv2.IMREAD_COLOR), rig["cameras"][name], boxes)
        tile = cv2.resize(image, TILE, interpolation=cv2.INTER_AREA)
        label(tile, name)
        tiles.append(tile)
    cameras = np.concatenate(
        [np.concatenate(tiles[:3], axis=1), np.concatenate(tiles[3:], axis=1)], axis=0
    )
    points = np.frombuffer(messages[topics.LIDAR].data, LIDAR_DTYPE)
    lidar = draw_lidar(points, np.array(rig["lidar"]["LIDAR_TOP"]["sensor_to_ego"]), boxes)
    label(lidar, f"LIDAR_TOP {len(points)} points, 100 m")
    top = cv2.resize(
        cv2.imdecode(np.frombuffer(messages[topics.BEV].data, np.uint8), cv2.IMREAD_COLOR),
        (LIDAR_PX, LIDAR_PX),
    )
    label(top, "/bev")
    side = np.concatenate([lidar, top], axis=1)
    width = cameras.shape[1]
    side = cv2.resize(
        side, (width, width * side.shape[0] // side.shape[1]), interpolation=cv2.INTER_AREA
    )
    sheet = np.concatenate([cameras, side], axis=0)
    cv2.putText(
        sheet,
        f"{scenario_id} frame {args.frame}",
        (8, cameras.shape[0] - 10),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.6,
        (255, 255, 255),
        1,
        cv2.LINE_AA,
    )
    cv2.imwrite(str(args.out), sheet)
    print(f"wrote {args.out}: {len(boxes)} boxes, {sum(bool(b.cameras) for b in boxes)} seen")


if __name__ == "__main__":
    main()
