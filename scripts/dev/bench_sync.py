"""What posing, ordering and uploading a frame's moving bodies costs (`GLRenderer.sync`), as a
GPU host's renderer does it (the scene cut into cells, one scene program), measured on any host:
the CPU's share of a closed-loop or collection step that no GPU takes over. The ego is placed
at its logged pose as the cameras' (hidden, casting its shadow), as a closed-loop step does.

    python scripts/dev/bench_sync.py DATA CLIP [--frames 60] [--pose-on gpu|cpu]

DATA holds scenario bundles (`drivee2e synth`). Prints the mean and median ms a frame over the
clip's first frames (the first five, which make the models' posers, left out). `--pose-on`:
where the actors' models are posed (a GPU host's default: the GPU, `gl_posed`; the CPU's
`PlacedModel` before). Run two versions or both ways alternately to compare them
(docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from drivee2e_data import store
from drivee2e_data.sim.world import World


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("clip")
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--pose-on", choices=("gpu", "cpu"), default="gpu")
    args = parser.parse_args()
    scenario = store.read_scenario(args.data, args.clip)
    with World(store.read_map(args.data, scenario.map_id), scenario, "gl") as world:
        world.gl.cull = True  # as on a GPU
        world.gl.one_program = True
        world.gl.poses_on_gpu = args.pose_on == "gpu"
        world.gl.forget_bodies()
        world.gl.set_models(world.body_models())
        seconds = []
        ego = scenario.ego
        for frame in range(1, min(args.frames, ego.x_m.shape[0])):
            # the cameras' ego, as a closed-loop step places it: hidden, casting its shadow
            world.place_ego(float(ego.x_m[frame]), float(ego.y_m[frame]), ego.track_id,
                            float(ego.yaw_rad[frame]))  # fmt: skip
            world.set_time(frame)
            start = time.perf_counter()
            world.gl.sync(world.state, world.animations, world.scene_lights)
            seconds.append(time.perf_counter() - start)
    kept = np.asarray(seconds[5:]) * 1000
    print(f"{args.clip}, posed on the {args.pose_on.upper()}: sync {kept.mean():.2f} ms a frame (median {np.median(kept):.2f}) "
          f"over {len(kept)} frames")  # fmt: skip


if __name__ == "__main__":
    main()
