"""Where a worker's world set-up goes when every worker sets up at once, as at a pool's start.

    python scripts/dev/profile_setup.py [--workers auto] [--gpus all] [--top 30] [--data DATA]

Makes `drivee2e synth --clips 16 --seed 0` (or takes a curated `--data` root) and starts
`--workers` processes the way `drivee2e collect` does (spawned, one EGL device each, round
robin over `--gpus`). Worker k then, timing each step: imports the collector, makes its GL
context, sets up clip k (a new world: its map's twin and the clip's actors) and captures two
sensor frames, sets up a clip on another map (a new twin in a warm process) and captures a frame,
then a clip on its first map again (only the actors are replaced) and captures a frame. Prints
each step's mean and slowest time over the workers, and the functions that cost most in the
first set-up (cProfile, cumulative seconds, mean over the workers).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import multiprocessing
import os
import pstats
import tempfile
import time
from pathlib import Path

STEPS = (
    "import",
    "context",
    "first set-up",
    "first frame",
    "second frame",
    "set-up, other map",
    "frame, other map",
    "set-up, same map",
    "frame, same map",
)


def _worker(k: int, root: str, clips: list[str], gpus: tuple[int, ...], folder: str) -> dict:
    """Worker k's step times (seconds); its first set-up's profile goes to `folder`."""
    import cProfile

    times = {}
    tick = time.perf_counter()
    from drivee2e_data.collect.job import CollectOptions, open_clip
    from drivee2e_data.sim import egl_devices
    from drivee2e_data.sim.gl_context import gl_available

    times["import"] = time.perf_counter() - tick
    egl_devices.use_device(egl_devices.device_for_worker(k, gpus))
    options = CollectOptions(renderer="gl", lidar="depth", sensor_hz=2)
    frames = range(0, 125)

    def timed(step: str, action):
        start = time.perf_counter()
        value = action()
        times[step] = time.perf_counter() - start
        return value

    profile = cProfile.Profile()
    profile.enable()
    timed("context", gl_available)
    setup = timed("first set-up", lambda: open_clip(Path(root), clips[k], options, frames))
    profile.disable()
    profile.dump_stats(os.path.join(folder, f"{k}.prof"))
    profile = cProfile.Profile()
    profile.enable()
    timed("first frame", lambda: setup.suite.capture(0))
    profile.disable()
    profile.dump_stats(os.path.join(folder, f"{k}.frame.prof"))
    timed("second frame", lambda: setup.suite.capture(5))
    other = clips[(k + 1) % len(clips)]  # the next clip: another map in the synthetic set
    setup = timed("set-up, other map", lambda: open_clip(Path(root), other, options, frames))
    timed("frame, other map", lambda: setup.suite.capture(0))
    same = clips[(k + 4) % len(clips)]  # four clips on: the first clip's map again
    setup = timed("set-up, same map", lambda: open_clip(Path(root), same, options, frames))
    timed("frame, same map", lambda: setup.suite.capture(0))
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", default="auto")
    parser.add_argument("--gpus", default="all")
    parser.add_argument("--top", type=int, default=30)
    parser.add_argument("--data", type=Path, help="a curated data root (default: synth 16 clips)")
    args = parser.parse_args()

    from drivee2e_data import store
    from drivee2e_data.cli import build_parser
    from drivee2e_data.cli import main as cli_main
    from drivee2e_data.cli.collection import plan_collect

    with tempfile.TemporaryDirectory() as folder:
        root = args.data
        if root is None:
            root = Path(folder) / "data"
            with contextlib.redirect_stdout(io.StringIO()):
                cli_main(["synth", "--out", str(root), "--clips", "16", "--seed", "0"])
        argv = ["collect", str(root), "--workers", args.workers, "--gpus", args.gpus]
        planned = plan_collect(build_parser().parse_args(argv))
        clips = store.scenario_ids(root)
        workers = min(planned.workers, len(clips))
        print(f"{workers} workers setting up at once, GPUs {planned.gpus or '(default)'}")
        context = multiprocessing.get_context("spawn")
        with context.Pool(workers) as pool:
            tasks = [(k, str(root), clips, planned.gpus, folder) for k in range(workers)]
            results = pool.starmap(_worker, tasks)
        print(f"{'step':<20}{'mean s':>8}{'max s':>8}")
        for step in STEPS:
            values = [r[step] for r in results]
            print(f"{step:<20}{sum(values) / len(values):8.3f}{max(values):8.3f}")
        for suffix, title in ((".prof", "the first set-up (context and world)"),
                              (".frame.prof", "the first frame")):  # fmt: skip
            files = (os.path.join(folder, f"{k}{suffix}") for k in range(workers))
            stats = pstats.Stats(*files)
            rows = sorted(
                ((cumulative / workers, own / workers, name, Path(filename).name, line)
                 for (filename, line, name), (_, _, own, cumulative, _) in stats.stats.items()),
                reverse=True,
            )  # fmt: skip
            print(f"\n{title}, mean s a worker:")
            print(f"  {'cumul.':>7} {'own':>7}  function")
            for cumulative, own, name, filename, line in rows[: args.top]:
                print(f"  {cumulative:7.3f} {own:7.3f}  {name} ({filename}:{line})")


if __name__ == "__main__":
    main()
