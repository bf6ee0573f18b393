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

import numpy as np

from drivee2e_data import store
from drivee2e_data.evaluate.observation import SensorObserver
from drivee2e_data.evaluate.traffic import Traffic
from drivee2e_data.sensors.ego_state import ego_motion
from drivee2e_data.sim.vehicle import VehicleState
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
    motion, traffic, ego = ego_motion(scenario), Traffic(scenario), scenario.ego
    steps = min(args.steps, len(motion.x_m) - 1)
    with World(store.read_map(args.data, scenario.map_id), scenario, "auto") as world:
        observer = SensorObserver(world, FRONT, (1600, 900), input_size)

        def step(frame: int) -> None:
            state = VehicleState(float(motion.x_m[frame]), float(motion.y_m[frame]),
                                 float(motion.yaw_rad[frame]), float(motion.speed_mps[frame]))  # fmt: skip
            centre = np.array([ego.x_m[frame], ego.y_m[frame]])
            poses = traffic.poses(frame, centre, state.yaw_rad, state.speed_mps,
                                  tuple(motion.size_m[:2]))  # fmt: skip
            signals = {s.signal_id: s.state_at(frame) for s in scenario.signals}
            observer.observe(frame, frame, state, float(motion.z_m[frame]), poses, signals, centre)

        step(0)
        profile = cProfile.Profile()
        start = time.perf_counter()
        profile.enable()
        for frame in range(1, steps + 1):
            step(frame)
        profile.disable()
        seconds = time.perf_counter() - start
    print(f"{args.clip}, {world.renderer} renderer, input {args.input}: "
          f"{1000 * seconds / steps:.1f} ms a step over {steps} steps (profiled)")  # fmt: skip
    stats = pstats.Stats(profile)
    stats.sort_stats("tottime").print_stats(args.top)
    stats.sort_stats("cumulative").print_stats(args.top)


if __name__ == "__main__":
    main()
