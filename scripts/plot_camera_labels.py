"""One logged frame's dense camera labels beside its images: per camera (rows) the RGB, the
depth (turbo colour map, near red to far blue, black for no hit), the semantic classes and the
agent instances, drawn from the log alone.

    python scripts/plot_camera_labels.py DATA SCENARIO_ID --frame K --out labels.jpg [--width 400]

The log must have been collected with `drivee2e collect --camera-labels depth,semantic,instance`.
A legend of the classes present is printed under the grid.
"""

from __future__ import annotations

import argparse
import zlib
from pathlib import Path

import cv2
import numpy as np

from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.sensors.camera_labels import SEMANTIC_CLASSES, decode_png

# BGR per semantic class
PALETTE = {
    "other": (90, 90, 90), "road": (128, 64, 128), "lane_marking": (255, 255, 255),
    "crosswalk": (0, 220, 255), "stop_line": (0, 0, 255), "sidewalk": (232, 35, 244),
    "building": (70, 70, 70), "vegetation": (35, 142, 107), "pole": (153, 153, 153),
    "traffic_light": (30, 170, 250), "car": (142, 0, 0), "van": (100, 60, 0),
    "truck": (70, 0, 0), "bus": (100, 80, 0), "pedestrian": (60, 20, 220),
    "cyclist": (32, 11, 119), "tricyclist": (0, 60, 100), "motorcyclist": (230, 0, 0),
    "sky": (180, 130, 70),
}  # fmt: skip


def colourise(kind: str, label: np.ndarray) -> np.ndarray:
    if kind == "depth":
        metres = label.astype(np.float32) / 1000.0
        scaled = np.clip(255 * (1 - np.log1p(metres) / np.log1p(80.0)), 0, 255).astype(np.uint8)
        image = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)
        image[label == 0] = 0
        return image
    if kind == "semantic":
        table = np.array([PALETTE[name] for name in SEMANTIC_CLASSES], np.uint8)
        return table[label]
    colours = np.zeros((int(label.max()) + 1, 3), np.uint8)
    for value in range(1, len(colours)):
        digest = zlib.crc32(str(value).encode())
        colours[value] = (60 + digest % 196, 60 + (digest >> 8) % 196, 60 + (digest >> 16) % 196)
    return colours[label]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("scenario_id")
    parser.add_argument("--frame", type=int, default=0)
    parser.add_argument("--width", type=int, default=400)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    with LogReader(args.data / "logs" / f"{args.scenario_id}.mcap") as log:
        kinds = log.camera_label_kinds
        if not kinds:
            raise SystemExit(f"{log.path}: collected without --camera-labels")
        names = [topics.image_topic(c) for c in log.cameras]
        names += [topics.camera_label_topic(c, k) for c in log.cameras for k in kinds]
        messages = log.frame(args.frame, names)
        cameras = log.cameras
    rows, present = [], set()
    for camera in cameras:
        jpeg = messages[topics.image_topic(camera)].data
        rgb = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
        height = round(rgb.shape[0] * args.width / rgb.shape[1])
        tiles = [cv2.resize(rgb, (args.width, height), interpolation=cv2.INTER_AREA)]
        for kind in kinds:
            label = decode_png(messages[topics.camera_label_topic(camera, kind)].data)
            if kind == "semantic":
                present.update(SEMANTIC_CLASSES[v] for v in np.unique(label))
            tile = cv2.resize(
                colourise(kind, label), (args.width, height), interpolation=cv2.INTER_NEAREST
            )
            tiles.append(tile)
        row = np.hstack(tiles)
        cv2.putText(row, camera, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2)
        rows.append(row)
    grid = np.vstack(rows)
    legend = np.full((68, grid.shape[1], 3), 255, np.uint8)
    x, y = 8, 9
    for name in SEMANTIC_CLASSES:
        if name not in present:
            continue
        if x + 28 + 9 * len(name) > legend.shape[1]:
            x, y = 8, y + 30
        cv2.rectangle(legend, (x, y), (x + 16, y + 16), PALETTE[name], -1)
        cv2.rectangle(legend, (x, y), (x + 16, y + 16), (0, 0, 0), 1)
        cv2.putText(legend, name, (x + 20, y + 14), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1)
        x += 28 + 9 * len(name)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), np.vstack([grid, legend]), [cv2.IMWRITE_JPEG_QUALITY, 82])
    print(f"wrote {args.out}: {len(cameras)} cameras x (RGB, {', '.join(kinds)})")


if __name__ == "__main__":
    main()
