"""Seconds per 1600x900 camera image with the GL renderer, pybullet's EGL plugin and
TinyRenderer (the reference), on a synthetic 4-way intersection with at least 40 agents.

    python scripts/dev/bench_render.py [--frames 10] [--seed 0]

Each renderer gets a fresh world, 3 warm-up images (EGL compiles shaders and uploads meshes on
the first ones), then `--frames` timed front-camera images at successive clip frames; the
median is reported. Run on a quiet machine.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from drivee2e_data import pipeline, store
from drivee2e_data.sim.world import World

WIDTH, HEIGHT, VERTICAL_FOV_DEG = 1600, 900, 42.0  # a 70-degree horizontal front camera


def four_way_clip(seed: int, folder: Path) -> tuple:
    """The first synthetic clip of `seed` on a 4-way site with 40 or more agents."""
    for clips in range(1, 30):
        pipeline.synthesize(folder, clips=clips, seed=seed, intersections=clips)
        scenario = store.read_scenario(folder, store.scenario_ids(folder)[-1])
        intersection_map = store.read_map(folder, scenario.map_id)
        if len(intersection_map.metadata["arms"]) == 4 and len(scenario.tracks) >= 40:
            return intersection_map, scenario
    raise SystemExit("no 4-way clip with 40 agents found")


def seconds_per_image(intersection_map, scenario, renderer: str, frames: int) -> tuple[float, str]:
    with World(intersection_map, scenario, renderer) as world:
        ego = scenario.ego
        times = []
        for index in range(3 + frames):
            frame = index % scenario.num_frames
            world.place_ego(float(ego.x_m[frame]), float(ego.y_m[frame]), ego.track_id)
            world.set_time(frame)
            eye = np.array([ego.x_m[frame], ego.y_m[frame], 1.6])
            target = eye + 10 * np.array(
                [np.cos(ego.yaw_rad[frame]), np.sin(ego.yaw_rad[frame]), 0.0]
            )
            start = time.perf_counter()
            world.render(eye, target, WIDTH, HEIGHT, VERTICAL_FOV_DEG)
            if index >= 3:
                times.append(time.perf_counter() - start)
        return statistics.median(times), world.renderer


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        intersection_map, scenario = four_way_clip(args.seed, Path(folder))
    print(
        f"scene: {scenario.scenario_id}, {len(scenario.tracks)} agents, {len(intersection_map.lanes)} lanes"
    )
    tiny, _ = seconds_per_image(intersection_map, scenario, "tiny", args.frames)
    print(f"TinyRenderer: {tiny:.3f} s per {WIDTH}x{HEIGHT} image")
    for renderer, name in (("egl", "pybullet EGL"), ("gl", "GL renderer")):
        try:
            seconds, used = seconds_per_image(intersection_map, scenario, renderer, args.frames)
        except Exception as error:  # not available here: say so, measure the others
            print(f"{name}: unavailable ({error})")
            continue
        print(f"{name} ({used}): {seconds:.3f} s per {WIDTH}x{HEIGHT} image, "
              f"{tiny / seconds:.2f}x TinyRenderer")  # fmt: skip


if __name__ == "__main__":
    main()
