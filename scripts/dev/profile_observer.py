"""cProfile of the closed-loop observer alone: the expert's logged poses of one clip through
`SensorObserver` (the agent's front cameras at its input size, the cheap path), no episode, no
agent: what a step's observing costs on this host, and where it goes.

    python scripts/dev/profile_observer.py DATA CLIP [--input 256x144] [--steps 40] [--top 25]

DATA holds scenario bundles (`drivee2e synth`; no logs needed). Prints the mean ms a step
(the first step, which compiles and uploads, left out) and the functions with the most own and
cumulative time. Run two versions alternately to compare them (docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time
from pathlib import Path

from drivee2e_data import store
from drivee2e_data.evaluate.observation import LoggedDrive, SensorObserver
from drivee2e_data.sim.world import World

FRONT = ("CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("clip")
    parser.add_argument("--input", default="256x144", help="the agent's input size, WxH")
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--top", type=int, default=25)
    args = parser.parse_args()
    input_size = tuple(int(v) for v in args.input.split("x"))
    scenario = store.read_scenario(args.data, args.clip)
    drive = LoggedDrive(scenario)
    steps = min(args.steps, len(drive.motion.x_m) - 1)
    with World(store.read_map(args.data, scenario.map_id), scenario, "auto") as world:
        observer = SensorObserver(world, FRONT, (1600, 900), input_size)

        drive.observe(observer, 0)
        profile = cProfile.Profile()
        start = time.perf_counter()
        profile.enable()
        for frame in range(1, steps + 1):
            drive.observe(observer, frame)
        profile.disable()
        seconds = time.perf_counter() - start
    print(f"{args.clip}, {world.renderer} renderer, input {args.input}: "
          f"{1000 * seconds / steps:.1f} ms a step over {steps} steps (profiled)")  # fmt: skip
    stats = pstats.Stats(profile)
    stats.sort_stats("tottime").print_stats(args.top)
    stats.sort_stats("cumulative").print_stats(args.top)


if __name__ == "__main__":
    main()
