"""`drivee2e collect` through the CLI with two versions of this code on the same clips, runs
alternating, so that a change's cost is measured against what users ran before it.

    python scripts/dev/bench_versions.py --base REV [--clips 16] [--seed 0] [--max-frames 30]
        [--repeats 2] [--workers auto] [--base-tree DIR] [--data ROOT] [-- EXTRA COLLECT ARGS]

The clips are `drivee2e synth --clips N --seed S` (every weather and time of day the seed
draws), curated once; each run collects all of them into a fresh logs folder with
`--workers auto` (the host plan) and `--max-frames` frames per clip (omit it for whole clips).
The base version is a git worktree of REV (or, with `--base-tree`, a folder holding that
version's files, for a machine without the repository: `git archive REV | tar -x -C DIR`)
imported ahead of the installed package; the other is the installed package (the working
tree, installed editable). Prints each run's frames/s (from the CLI's summary line), the mean per
version, the ratio (working tree / base) and MB of log per frame.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # the repository (this is scripts/dev/)
RATE = re.compile(r"(\d+) frames in ([\d.]+) s \(([\d.]+) frames/s\)")


def base_tree(revision: str, folder: Path, files: Path | None) -> Path:
    """A worktree of `revision` (or a copy of `files`) importable from a PYTHONPATH entry
    (`collect/` and `loaders/` linked into the package, as the installed package maps them)."""
    tree = folder / "base"
    if files is not None:
        shutil.copytree(
            files,
            tree,
            ignore=shutil.ignore_patterns("drivee2e_data/collect", "drivee2e_data/loaders"),
        )
    else:
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), revision],
                       check=True, capture_output=True)  # fmt: skip
    for name in ("collect", "loaders"):
        (tree / "drivee2e_data" / name).symlink_to(tree / name, target_is_directory=True)
    return tree


def cli(arguments: list[str], pythonpath: Path | None) -> str:
    environment = dict(os.environ)
    if pythonpath is not None:
        environment["PYTHONPATH"] = f"{pythonpath}{os.pathsep}{environment.get('PYTHONPATH', '')}"
    # the `drivee2e` command's entry point (`launch`, which starts a pool's server first), or, in
    # a version without one, its command line
    tree = ROOT if pythonpath is None else pythonpath
    entry = "launch" if (tree / "drivee2e_data" / "launch.py").exists() else "cli"
    command = [
        sys.executable,
        "-c",
        f"import sys; from drivee2e_data.{entry} import main; sys.exit(main())",
    ]
    # run outside the checkout: `python -c` puts the working directory first on sys.path
    done = subprocess.run([*command, *arguments], env=environment, capture_output=True, text=True,
                          cwd=tempfile.gettempdir())  # fmt: skip
    if done.returncode != 0:
        raise SystemExit(f"drivee2e {' '.join(arguments)} failed:\n{done.stdout}\n{done.stderr}")
    return done.stdout + done.stderr


RENDER_SNIPPET = """
import sys, time
from pathlib import Path
from drivee2e_data import store
from drivee2e_data.sensors.camera import camera_to_world
from drivee2e_data.sensors.ego_state import ego_motion
from drivee2e_data.sensors.rig import default_rig
from drivee2e_data.sim.world import World
root, frames = Path(sys.argv[1]), int(sys.argv[2])
cameras = default_rig().cameras
for scenario_id in store.scenario_ids(root):
    scenario = store.read_scenario(root, scenario_id)
    with World(store.read_map(root, scenario.map_id), scenario, "gl") as world:
        ego, motion = scenario.ego, ego_motion(scenario)
        times = []
        for frame in range(frames + 1):
            world.place_ego(float(ego.x_m[frame]), float(ego.y_m[frame]), ego.track_id)
            world.set_time(frame)
            start = time.perf_counter()
            for camera in cameras:
                pose = camera_to_world(camera, motion.ego_to_world(frame))
                eye = pose[:3, 3]
                world.render(eye, eye + 10 * pose[:3, 2], camera.width, camera.height,
                             camera.vertical_fov_deg, near_m=0.5, far_m=200.0, native=True)
            if frame:  # the first frame compiles and uploads
                times.append(time.perf_counter() - start)
        conditions = scenario.conditions
        print(scenario_id, conditions.weather.value, conditions.time_of_day.value,
              f"{1000 * sum(times) / len(times):.1f}", flush=True)
"""


def render_times(data: Path, pythonpath: Path | None, frames: int) -> dict[str, tuple[str, float]]:
    """Milliseconds to draw a frame's six cameras, per clip (the version at `pythonpath`)."""
    environment = dict(os.environ)
    if pythonpath is not None:
        environment["PYTHONPATH"] = f"{pythonpath}{os.pathsep}{environment.get('PYTHONPATH', '')}"
    done = subprocess.run([sys.executable, "-c", RENDER_SNIPPET, str(data), str(frames)],
                          env=environment, capture_output=True, text=True, check=True,
                          cwd=tempfile.gettempdir())  # fmt: skip
    rows = [line.split() for line in done.stdout.splitlines() if line.startswith("synth")]
    return {row[0]: (f"{row[1]}, {row[2]}", float(row[3])) for row in rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", required=True, help="git revision to compare against")
    parser.add_argument("--clips", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-frames", type=int, default=30, help="0: whole clips")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--workers", default="auto")
    parser.add_argument("--base-tree", type=Path, default=None, help="the base version's files")
    parser.add_argument("--data", type=Path, default=None,
                        help="a synthesised, curated root to copy instead of synthesising")  # fmt: skip
    parser.add_argument("--render", type=int, default=0, metavar="FRAMES",
                        help="also time drawing the six cameras over this many frames a clip")  # fmt: skip
    parser.add_argument("extra", nargs="*", help="more `drivee2e collect` arguments (after --)")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="bench_versions_"))
    try:
        base = base_tree(args.base, folder, args.base_tree)
        data = folder / "data"
        if args.data is not None:  # its scenarios and maps; logs are made by the runs
            data.mkdir()
            for part in ("scenarios", "maps"):
                shutil.copytree(args.data / part, data / part)
        else:
            cli(
                ["synth", "--out", str(data), "--clips", str(args.clips), "--seed", str(args.seed)],
                None,
            )
            cli(["curate", str(data)], None)
        collect = ["collect", str(data), "--workers", args.workers, *args.extra]
        if args.max_frames:
            collect += ["--max-frames", str(args.max_frames)]
        rates: dict[str, list[float]] = {"base": [], "working tree": []}
        walls: dict[str, list[float]] = {"base": [], "working tree": []}  # the whole command's
        sizes: dict[str, float] = {}
        for repeat in range(args.repeats):
            for name, path in (("base", base), ("working tree", None)):
                shutil.rmtree(data / "logs", ignore_errors=True)
                start = time.perf_counter()
                output = cli(collect, path)
                wall = time.perf_counter() - start
                match = RATE.search(output)
                if match is None:
                    raise SystemExit(f"no rate in the collector's output:\n{output}")
                frames, rate = int(match.group(1)), float(match.group(3))
                log_bytes = sum(p.stat().st_size for p in (data / "logs").glob("*.mcap"))
                sizes[name] = log_bytes / 1e6 / frames
                rates[name].append(rate)
                walls[name].append(wall)
                print(f"run {repeat + 1} {name:13s} {frames} frames  {rate:.2f} frames/s  "
                      f"(CLI wall {wall:.1f} s: {frames / wall:.2f} frames/s)  "
                      f"{sizes[name]:.3f} MB a frame", flush=True)  # fmt: skip
        if args.render:
            base_times = render_times(data, base, args.render)
            new_times = render_times(data, None, args.render)
            print(
                "clip            conditions               six cameras (ms): base  working tree  ratio"
            )
            for clip, (conditions, before) in base_times.items():
                after = new_times[clip][1]
                print(f"{clip}  {conditions:24s} {before:8.1f} {after:12.1f} {after / before:6.2f}")
            total_before = sum(v for _, v in base_times.values())
            total_after = sum(v for _, v in new_times.values())
            print(f"mean over clips: {total_before / len(base_times):.1f} -> "
                  f"{total_after / len(new_times):.1f} ms a frame")  # fmt: skip
        means = {name: sum(values) / len(values) for name, values in rates.items()}
        print(f"base {args.base}: {means['base']:.2f} frames/s; working tree: "
              f"{means['working tree']:.2f} frames/s; ratio {means['working tree'] / means['base']:.3f}; "
              f"log {sizes['base']:.3f} -> {sizes['working tree']:.3f} MB a frame")  # fmt: skip
        process = {name: sum(values) / len(values) for name, values in walls.items()}
        print(f"the whole command (start to exit): base {process['base']:.1f} s, working tree "
              f"{process['working tree']:.1f} s; ratio {process['base'] / process['working tree']:.3f}")  # fmt: skip
    finally:
        subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(folder / "base")],
                       capture_output=True)  # fmt: skip
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
