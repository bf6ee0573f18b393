"""The vector map labels of one sample drawn over the logged top view.

    python scripts/plot_map_labels.py DATA SCENARIO_ID --frame K --out map_labels.png
        [--split-name default]

The top view is the log's `/bev` image (100 m across, centred on the ego's rear axle, heading
up); the labels are the Dataset's `gt_map_pts` (LiDAR frame) moved into the ego frame with
`lidar2ego`: dividers orange, crossings blue, road boundaries red, the 60 x 30 m patch dashed.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from drivee2e_data.loaders import DriveE2EDataset
from drivee2e_data.loaders.map_labels import DEFAULT_PATCH_M, MAP_CLASSES
from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.sensors.bev import DEFAULT_HALF_WIDTH_M

COLOURS_BGR = {"divider": (0, 140, 255), "ped_crossing": (255, 120, 0), "boundary": (40, 40, 230)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("scenario_id")
    parser.add_argument("--frame", type=int, default=0)
    parser.add_argument("--split-name", default="default")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    dataset = DriveE2EDataset(args.data, "all", args.split_name, cameras=())
    sample = dataset[dataset.samples.index((args.scenario_id, args.frame))]
    with LogReader(args.data / "logs" / f"{args.scenario_id}.mcap") as log:
        jpeg = log.frame(args.frame, [topics.BEV])[topics.BEV].data
    image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    size = image.shape[0]
    scale = (size / 2) / DEFAULT_HALF_WIDTH_M

    def pixels(ego_xy: np.ndarray) -> np.ndarray:  # ego x up, ego y left
        return np.round(
            np.column_stack([size / 2 - ego_xy[:, 1] * scale, size / 2 - ego_xy[:, 0] * scale])
        ).astype(np.int32)

    lidar_to_ego = sample["lidar2ego"].numpy()
    for line, label in zip(
        sample["gt_map_pts"].double().numpy(), sample["gt_map_labels"].tolist(), strict=True
    ):
        ego = line @ lidar_to_ego[:2, :2].T + lidar_to_ego[:2, 3]
        colour = COLOURS_BGR[MAP_CLASSES[label]]
        cv2.polylines(image, [pixels(ego)], False, colour, 2, cv2.LINE_AA)
        for point in pixels(ego):
            cv2.circle(image, tuple(int(v) for v in point), 2, colour, -1, cv2.LINE_AA)
    half_x, half_y = DEFAULT_PATCH_M[0] / 2, DEFAULT_PATCH_M[1] / 2
    corners = np.array([[half_x, half_y], [half_x, -half_y], [-half_x, -half_y], [-half_x, half_y]])
    corners = corners + lidar_to_ego[:2, 3]
    for a, b in zip(pixels(corners), np.roll(pixels(corners), -1, axis=0), strict=True):
        for t in np.linspace(0.0, 1.0, 30)[::2]:
            start = a + (b - a) * t
            end = a + (b - a) * min(1.0, t + 1 / 30)
            cv2.line(
                image, tuple(int(v) for v in start), tuple(int(v) for v in end), (255, 255, 255), 1
            )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), image)
    print(f"wrote {args.out}: {len(sample['gt_map_labels'])} polylines")


if __name__ == "__main__":
    main()
