"""Load a `drivee2e export nuscenes` folder with the official nuscenes-devkit and render one
sample: run it with the devkit's Python (its pins clash with this package, so it lives in its
own environment; `scripts/test.sh` makes `.venv-nuscenes`).

    .venv-nuscenes/bin/python scripts/check_nuscenes_export.py ROOT VERSION OUT_DIR [--sample K]

Prints a JSON summary (tables' sizes, scenes, the rendered sample's boxes) and writes
OUT_DIR/camera.png (CAM_FRONT with its boxes), OUT_DIR/camera_plain.png (without) and
OUT_DIR/lidar.png.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

from nuscenes.nuscenes import NuScenes


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("root")
    parser.add_argument("version")
    parser.add_argument("out", type=Path)
    parser.add_argument("--sample", type=int, default=0)
    args = parser.parse_args()
    nusc = NuScenes(version=args.version, dataroot=args.root, verbose=False)
    nusc.list_scenes()
    sample = nusc.sample[args.sample]
    camera = sample["data"]["CAM_FRONT"]
    args.out.mkdir(parents=True, exist_ok=True)
    nusc.render_sample_data(camera, out_path=str(args.out / "camera.png"), verbose=False)
    nusc.render_sample_data(
        camera, with_anns=False, out_path=str(args.out / "camera_plain.png"), verbose=False
    )
    nusc.render_sample_data(
        sample["data"]["LIDAR_TOP"], out_path=str(args.out / "lidar.png"), verbose=False
    )
    _, boxes, _ = nusc.get_sample_data(camera)
    summary = {
        "tables": {name: len(getattr(nusc, name)) for name in nusc.table_names},
        "scenes": [scene["name"] for scene in nusc.scene],
        "camera_boxes": [box.name for box in boxes],
        "colours": {box.name: list(nusc.colormap[box.name]) for box in boxes},
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
