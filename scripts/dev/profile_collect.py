"""Where one collector worker's time goes: the functions that cost most per frame, by cProfile.

    python scripts/dev/profile_collect.py [--frames 30] [--lidar depth] [--post-process cpu]
        [--top 25] [--out FILE] [--data DATA --clip ID]

Collects the benchmark clip of `bench_collect.py` (the first synthetic 4-way clip with 40 or more
agents) in this process, one worker, with the full sensor suite, under cProfile; prints the
`--top` functions by their own time and by cumulative time, both in milliseconds per frame, and
the stage table. `--data DATA --clip ID` profiles that clip of a data root instead (a curated
one, e.g. of the real mix `drivee2e synth --clips 16 --seed 0`). `--out` also writes the raw
profile (for `python -m pstats` or snakeviz).
Run on a quiet machine: one worker, nothing competing for the core, is the number a worker costs
when there are cores for all of them.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import tempfile
from pathlib import Path

from bench_collect import run, stage_table
from bench_render import four_way_clip

from drivee2e_data import store
from drivee2e_data.collect.job import CollectOptions


def print_top(profile: pstats.Stats, frames: int, key: str, top: int) -> None:
    """The `top` functions by `key` ("tottime" or "cumtime"), ms per frame."""
    rows = []
    for (filename, line, name), (_, calls, own, cumulative, _) in profile.stats.items():
        rows.append(
            (own if key == "tottime" else cumulative, own, cumulative, calls, filename, line, name)
        )
    rows.sort(reverse=True)
    print(f"\nby {'own' if key == 'tottime' else 'cumulative'} time (ms per frame):")
    print(f"  {'own':>8} {'cumul.':>8} {'calls/fr':>8}  function")
    for _, own, cumulative, calls, filename, line, name in rows[:top]:
        where = f"{Path(filename).name}:{line}" if line else filename
        print(
            f"  {1000 * own / frames:8.2f} {1000 * cumulative / frames:8.2f} "
            f"{calls / frames:8.1f}  {name} ({where})"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--lidar", choices=("raycast", "depth"), default="depth")
    parser.add_argument("--post-process", choices=("cpu", "cuda"), default="cpu")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--top", type=int, default=25)
    parser.add_argument("--out", type=Path, default=None, help="also write the raw profile here")
    parser.add_argument("--data", type=Path, default=None, help="a data root holding --clip")
    parser.add_argument("--clip", default=None, help="the clip of --data to profile")
    args = parser.parse_args()
    if (args.data is None) != (args.clip is None):
        parser.error("--data and --clip go together")
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder) / "data"
        if args.data is None:
            intersection_map, scenario = four_way_clip(args.seed, Path(folder) / "search")
        else:
            scenario = store.read_scenario(args.data, args.clip)
            intersection_map = store.read_map(args.data, scenario.map_id)
        store.write_map(root, intersection_map)
        store.write_scenario(root, scenario)
        profiler = cProfile.Profile()
        profiler.enable()
        summary = run(
            root,
            CollectOptions(
                max_frames=args.frames, lidar=args.lidar, post_process=args.post_process
            ),
            workers=1,
        )
        profiler.disable()
    if args.out:
        profiler.dump_stats(args.out)
    profile = pstats.Stats(profiler)
    print(
        f"{summary.frames} frames, {args.lidar} LiDAR, {args.post_process} post-processing, "
        "one worker in this process"
    )
    print("stages (ms per frame, under the profiler):")
    for stage, milliseconds in stage_table(summary).items():
        print(f"  {stage:<13} {milliseconds:7.1f}")
    print_top(profile, summary.frames, "tottime", args.top)
    print_top(profile, summary.frames, "cumtime", args.top)


if __name__ == "__main__":
    main()
