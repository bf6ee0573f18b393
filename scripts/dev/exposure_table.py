"""How bright the logged cameras are: one camera's mean grey level (the JPEG decoded to grey)
at every sensor frame of each clip, with its exposure as logged (`/CAM_*/exposure`, look 10 on:
the gain and what the meter read), per clip and per time of day; and how much the gain moves
from one sensor frame to the next (flicker), in stops (log2 of the ratio).

    python scripts/dev/exposure_table.py DATA [--camera CAM_FRONT]

DATA holds collected logs (`drivee2e synth --clips 16 --seed 0`, then `drivee2e collect DATA
--max-frames 20`). The per-time-of-day table is docs/twins.md's: the range of the frames' means,
the range of the clips' means, and the gains.
"""

from __future__ import annotations

import argparse
import itertools
import math
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.scenario import TimeOfDay


def clip_frames(path: Path, camera: str) -> tuple[dict, list[float], list[float]]:
    """(conditions, each sensor frame's mean grey, each frame's logged gain) of one log's
    camera; gains are 1 for logs without the exposure topic (looks before 10)."""
    image, exposure = topics.image_topic(camera), topics.exposure_topic(camera)
    means, gains = [], []
    with LogReader(path) as log:
        recorded = {channel.topic for channel in log.summary.channels.values()}
        wanted = [image, exposure] if exposure in recorded else [image]
        for frame in log.sensor_frames:
            messages = log.frame(frame, wanted)
            data = np.frombuffer(messages[image].data, np.uint8)
            means.append(float(cv2.imdecode(data, cv2.IMREAD_GRAYSCALE).mean()))
            gains.append(messages[exposure].gain if exposure in messages else 1.0)
        return log.scenario_meta["conditions"], means, gains


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--camera", default="CAM_FRONT")
    args = parser.parse_args()
    frames: dict[str, list[float]] = defaultdict(list)
    clips: dict[str, list[float]] = defaultdict(list)
    gains: dict[str, list[float]] = defaultdict(list)
    steps: list[float] = []  # |log2 gain ratio| between consecutive sensor frames
    print(f"{'clip':<18} {'time of day':<14} {'weather':<9} {'mean':>6} {'frames':>9} gain")
    for path in sorted((args.data / "logs").glob("*.mcap")):
        conditions, means, clip_gains = clip_frames(path, args.camera)
        time_of_day = conditions["time_of_day"]
        frames[time_of_day] += means
        clips[time_of_day].append(float(np.mean(means)))
        gains[time_of_day] += clip_gains
        steps += [abs(math.log2(b / a)) for a, b in itertools.pairwise(clip_gains)]
        print(f"{path.stem:<18} {time_of_day:<14} {conditions['weather']:<9} "
              f"{np.mean(means):6.1f} {min(means):4.0f}-{max(means):<4.0f} "
              f"{min(clip_gains):.2f}-{max(clip_gains):.2f}")  # fmt: skip
    print(f"\n| time of day | clips | {args.camera} frames' mean grey | clips' means | gain |")
    print("|---|---|---|---|---|")
    for time_of_day in TimeOfDay:
        if time_of_day.value in frames:
            f, c, g = frames[time_of_day.value], clips[time_of_day.value], gains[time_of_day.value]
            print(f"| {time_of_day.value} | {len(c)} | {min(f):.0f}-{max(f):.0f} | "
                  f"{min(c):.0f}-{max(c):.0f} | {min(g):.2f}-{max(g):.2f} |")  # fmt: skip
    if steps:
        print(f"\nthe gain from one sensor frame to the next: median {np.median(steps):.3f}, "
              f"95th percentile {np.percentile(steps, 95):.3f}, max {max(steps):.3f} stops "
              f"({len(steps)} steps)")  # fmt: skip


if __name__ == "__main__":
    main()
