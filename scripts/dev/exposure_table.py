"""How bright the logged cameras are: the mean (and median) grey level of one camera's JPEGs per
clip, then per time of day, with each clip's weather and the exposure gain its log records.

    python scripts/dev/exposure_table.py DATA [--camera CAM_FRONT] [--markdown]

DATA holds collected logs (`drivee2e synth --clips 16 --seed 0`, curated, collected); every
sensor frame of each log is read. Prints one row per clip and one per time of day (the clips'
means: their range and their mean).
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.scenario import TimeOfDay


def clip_brightness(path: Path, camera: str) -> tuple[dict, float, float, str]:
    """(conditions, mean grey, median grey, exposure as logged) of one log's camera."""
    topic = topics.image_topic(camera)
    means, medians = [], []
    with LogReader(path) as log:
        for frame in log.sensor_frames:
            data = log.frame(frame, [topic])[topic].data
            grey = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
            means.append(float(grey.mean()))
            medians.append(float(np.median(grey)))
        exposure = log.collection.get("camera_exposure", "-")
        return (
            log.scenario_meta["conditions"],
            float(np.mean(means)),
            float(np.mean(medians)),
            exposure,
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--camera", default="CAM_FRONT")
    args = parser.parse_args()
    by_time: dict[str, list[float]] = defaultdict(list)
    print(f"{'clip':<18} {'time of day':<14} {'weather':<9} {'mean':>6} {'median':>7} exposure")
    for path in sorted((args.data / "logs").glob("*.mcap")):
        conditions, mean, median, exposure = clip_brightness(path, args.camera)
        time_of_day = conditions["time_of_day"]
        by_time[time_of_day].append(mean)
        print(f"{path.stem:<18} {time_of_day:<14} {conditions['weather']:<9} {mean:6.1f} "
              f"{median:7.1f} {exposure}")  # fmt: skip
    print(f"\n| time of day | clips | {args.camera} mean grey: range | mean |\n|---|---|---|---|")
    for time_of_day in TimeOfDay:
        values = by_time.get(time_of_day.value)
        if values:
            print(f"| {time_of_day.value} | {len(values)} | {min(values):.0f}-{max(values):.0f} "
                  f"| {np.mean(values):.0f} |")  # fmt: skip


if __name__ == "__main__":
    main()
