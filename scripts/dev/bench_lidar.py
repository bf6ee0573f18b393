"""The depth-image LiDAR against the ray-cast one (the reference), on one frame of the first
synthetic 4-way clip with at least 40 agents, in one process:

    python scripts/dev/bench_lidar.py [--repeats 5] [--frame 80] [--oversample 1.0]

Prints the renderer, seconds per sweep of each and their ratio, and how they agree: the median
and 90th percentile of the range difference on beams both see, the rings each returns, and the
points on every agent box with 50 or more.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_render import four_way_clip

from drivee2e_data.sensors import lidar
from drivee2e_data.sensors.lidar_depth import OVERSAMPLE, ROW_SCALE, depth_sweep
from drivee2e_data.sensors.suite import SensorSuite
from drivee2e_data.sim.world import World


def timed(function, repeats: int):
    function()  # warm up (first renders set up buffers)
    start = time.perf_counter()
    for _ in range(repeats):
        result = function()
    return result, (time.perf_counter() - start) / repeats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--frame", type=int, default=80)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--oversample", type=float, default=OVERSAMPLE,
        help=f"depth views' pixels per azimuth step (default {OVERSAMPLE})",
    )  # fmt: skip
    parser.add_argument(
        "--row-scale", type=float, default=ROW_SCALE,
        help=f"depth views' rows per column's worth of angle (default {ROW_SCALE})",
    )  # fmt: skip
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        intersection_map, scenario = four_way_clip(args.seed, Path(folder))
    with World(intersection_map, scenario) as world:
        suite = SensorSuite(world)
        frame, ego, rig_lidar = args.frame, scenario.ego, suite.rig.lidar
        world.place_ego(float(ego.x_m[frame]), float(ego.y_m[frame]), ego.track_id)
        world.set_time(frame)
        to_world = suite.motion.ego_to_world(frame) @ rig_lidar.sensor_to_ego
        paint = world.twin.paint_raster()
        kinds = world.twin.segmentation
        cast, cast_s = timed(
            lambda: lidar.sweep(world.client, rig_lidar, to_world, kinds, paint), args.repeats
        )
        read, read_s = timed(
            lambda: depth_sweep(world, rig_lidar, to_world, paint, args.oversample, args.row_scale),
            args.repeats,
        )
        agents = sorted(world.bodies.values())
        print(f"renderer: {world.renderer}; clip {scenario.scenario_id}, frame {frame}")
    print(f"ray casting (reference) {1000 * cast_s:7.1f} ms a sweep, {len(cast.ring)} points")
    print(
        f"depth images            {1000 * read_s:7.1f} ms a sweep, {len(read.ring)} points "
        f"({args.oversample:g} pixels per azimuth step, {args.row_scale:g} rows per column)"
    )
    print(f"ratio                   {cast_s / read_s:7.2f}x")
    a, b = lidar.ranges_per_beam(cast, rig_lidar), lidar.ranges_per_beam(read, rig_lidar)
    both = np.isfinite(a) & np.isfinite(b)
    difference = np.abs(a[both] - b[both])
    print(
        f"beams both see: {both.sum()}; range difference median {100 * np.median(difference):.2f} "
        f"cm, 90th percentile {100 * np.percentile(difference, 90):.1f} cm, 99th "
        f"{100 * np.percentile(difference, 99):.1f} cm"
    )
    print(
        f"beams only ray casting sees: {(np.isfinite(a) & ~np.isfinite(b)).sum()}; only the "
        f"depth images: {(~np.isfinite(a) & np.isfinite(b)).sum()}"
    )
    print(f"rings: {len(np.unique(cast.ring))} and {len(np.unique(read.ring))}")
    counts = [(int((cast.body == k).sum()), int((read.body == k).sum())) for k in agents]
    boxes = [(x, y) for x, y in counts if x >= 50]
    worst = max((abs(y - x) / x for x, y in boxes), default=0.0)
    print(f"agent boxes with 50+ points: {len(boxes)}; worst count difference {100 * worst:.1f}%")
    small = [(x, y) for x, y in counts if 0 < x < 50 or 0 < y < 50]
    print(
        f"agent boxes with 1-49 points: {len(small)}; points {sum(x for x, _ in small)} ray cast, "
        f"{sum(y for _, y in small)} from depth; seen by one only: "
        f"{sum((x == 0) != (y == 0) for x, y in small)}"
    )


if __name__ == "__main__":
    main()
