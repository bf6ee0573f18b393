"""Collection speed, memory and log size for the whole sensor suite at full resolution.

By default, what a user runs: the real mix.

    python scripts/dev/bench_collect.py [--clips 16] [--seed 0] [--max-frames N] [--workers auto]
        [--gpus all|0,1] [--sensor-hz 10|2] [--identical K] [--json FILE] [--timeline PNG]

makes `drivee2e synth --clips 16 --seed 0` (every weather and time of day; `--data DIR` copies
a set made before instead), collects it whole
(or `--max-frames` frames a clip) the way `drivee2e collect DATA --workers auto` does (the CLI's
own planning, `cli.collection.plan_collect`), and prints frames/s, the wall time against the
summed work of all units divided by the workers (the straggler share), a stage table per
condition (weather x time of day, ms a frame), the slowest condition against the clear-day clip,
peak memory and MB of log a frame, and where the workers' wall time went (the pool's start
before each worker's first job, gaps between jobs, the tail after a worker's last job, the index;
`--timeline PNG` draws every job on its worker's row). Every log is validated; with `--identical K`, the K shortest
clips are collected again by one worker and compared byte for byte.

The single-clip mode (`--single`) is the earlier benchmark, a favourable case to show beside it:

    python scripts/dev/bench_collect.py --single [--frames 100] [--workers 2] [--reference-frames 8]
        [--camera-labels depth,semantic,instance [--label-scale 4]] [--lidar depth]
        [--post-process cuda] [--renderer auto|gl|egl|tiny] [--no-plain]

The clip is the first synthetic 4-way clip with at least 40 agents (as in bench_render.py),
written under max(2, --workers) scenario ids so that every worker has a job; each is collected for
`--frames` frames with six 1600x900 cameras, the 64-channel LiDAR, five radars, the top view and
annotations. The reference is the same suite in one process with pybullet's TinyRenderer (the
naive pipeline), over `--reference-frames` frames. Prints frames/s of both and their ratio, the
per-stage time per frame, peak memory per worker and megabytes of log per frame. With
`--camera-labels`, the suite runs with the dense labels and again without them (the reference
for their cost), and the slowdown and the log size of both are printed; with `--lidar depth`,
the suite runs with the depth-image LiDAR and again with ray casting (the reference for it), and
the speed-up and both LiDAR stage times are printed; with `--post-process cuda` (camera weather,
resize and JPEG with torch and nvJPEG), the suite runs again with the defaults (ray-cast LiDAR,
OpenCV post-processing) as the reference. `--reference-frames 0` skips the TinyRenderer reference.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import itertools
import json
import shutil
import tempfile
import time
from pathlib import Path

from bench_render import four_way_clip

from drivee2e_data import store
from drivee2e_data.cli import build_parser
from drivee2e_data.cli import main as cli_main
from drivee2e_data.cli.collection import plan_collect, start_pool_server
from drivee2e_data.collect.job import FRAME_STAGES, JOB_STAGES, CollectOptions, log_path
from drivee2e_data.collect.runner import CollectSummary, collect
from drivee2e_data.logs.reader import validate
from drivee2e_data.sim.world import RENDERERS


def run(root: Path, options: CollectOptions, workers: int) -> CollectSummary:
    summary = collect(root, options, workers=workers)
    failed = summary.of("failed")
    if failed:
        raise SystemExit(f"collection failed: {failed[0].scenario_id}: {failed[0].error}")
    return summary


def stage_table(summary: CollectSummary) -> dict[str, float]:
    """Milliseconds per frame in each stage, summed over workers."""
    frames = summary.frames
    totals = dict.fromkeys(JOB_STAGES, 0.0)
    for result in summary.of("collected"):
        for stage, seconds in result.stage_seconds.items():
            totals[stage] += seconds
    return {stage: 1000 * seconds / frames for stage, seconds in totals.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--single", action="store_true", help="one clip copied per worker")
    parser.add_argument("--clips", type=int, default=16, help="real mix: clips of synth")
    parser.add_argument("--max-frames", type=int, default=None, help="real mix: frames a clip")
    parser.add_argument(
        "--data", type=Path, default=None,
        help="real mix: copy this data root's scenarios and maps instead of running synth "
        "(its logs are neither read nor touched)",
    )  # fmt: skip
    parser.add_argument("--gpus", default="all", help="real mix: as drivee2e collect --gpus")
    parser.add_argument("--sensor-hz", default="10", help="real mix: as drivee2e collect")
    parser.add_argument(
        "--identical", type=int, default=0,
        help="real mix: collect the K shortest clips again with one worker, compare bytes",
    )  # fmt: skip
    parser.add_argument(
        "--frames", type=int, default=100, help="single: frames per job (clips are 150-250)"
    )
    parser.add_argument("--workers", default=None, help="real mix: auto; single: 2")
    parser.add_argument("--reference-frames", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None, help="also write the numbers here")
    parser.add_argument("--timeline", type=Path, default=None, help="real mix: draw jobs here")
    parser.add_argument("--camera-labels", default="", help="e.g. depth,semantic,instance")
    parser.add_argument("--label-scale", type=int, default=4)
    parser.add_argument("--lidar", choices=("raycast", "depth"), default="raycast")
    parser.add_argument("--post-process", choices=("cpu", "cuda"), default="cpu")
    parser.add_argument(
        "--renderer", choices=RENDERERS, default="auto",
        help="the suite's renderer (the plain run and the TinyRenderer reference keep theirs)",
    )  # fmt: skip
    parser.add_argument(
        "--no-plain", action="store_true",
        help="skip the run with the default options (the reference for --lidar, --post-process "
        "and --camera-labels); for comparing two versions of the code, each its own reference",
    )  # fmt: skip
    args = parser.parse_args()
    if not args.single:
        mix(args)
        return
    args.workers = int(args.workers or 2)
    kinds = tuple(k for k in args.camera_labels.split(",") if k)
    # one job per worker at least (two at least), so every worker has a clip to collect
    suffixes = [f"j{k}" for k in range(max(2, args.workers))]
    labelled = CollectOptions(
        max_frames=args.frames,
        camera_labels=kinds,
        label_scale=args.label_scale,
        lidar=args.lidar,
        post_process=args.post_process,
        renderer=args.renderer,
    )
    with tempfile.TemporaryDirectory() as folder:
        intersection_map, scenario = four_way_clip(args.seed, Path(folder) / "search")
        root = Path(folder) / "data"
        store.write_map(root, intersection_map)
        for suffix in suffixes:
            store.write_scenario(
                root, dataclasses.replace(scenario, scenario_id=f"{scenario.scenario_id}_{suffix}")
            )
        print(
            f"clip {scenario.scenario_id}: {len(scenario.tracks)} agents, "
            f"{len(intersection_map.metadata['arms'])}-way, {scenario.conditions.weather.value}, "
            f"{scenario.conditions.time_of_day.value}; {args.frames} frames x {len(suffixes)} jobs"
        )
        ours_start = time.perf_counter()
        ours = run(root, labelled, args.workers)
        ours_wall = time.perf_counter() - ours_start
        plain, plain_wall = None, float("nan")
        if labelled != CollectOptions(max_frames=args.frames) and not args.no_plain:
            plain_root = Path(folder) / "plain"
            store.write_map(plain_root, intersection_map)
            for suffix in suffixes:
                store.write_scenario(plain_root, dataclasses.replace(
                    scenario, scenario_id=f"{scenario.scenario_id}_{suffix}"))  # fmt: skip
            plain_start = time.perf_counter()
            plain = run(plain_root, CollectOptions(max_frames=args.frames), args.workers)
            plain_wall = time.perf_counter() - plain_start
            plain_mb = sum(r.log_bytes for r in plain.of("collected")) / plain.frames / 1e6
        reference = None
        if args.reference_frames > 0:
            reference_root = Path(folder) / "reference"
            store.write_map(reference_root, intersection_map)
            store.write_scenario(reference_root, scenario)
            reference = run(
                reference_root,
                CollectOptions(renderer="tiny", max_frames=args.reference_frames),
                workers=1,
            )
    plain_fps = plain.frames / plain_wall if plain is not None else float("nan")
    collected = ours.of("collected")
    ours_fps = ours.frames / ours_wall
    reference_fps = reference.frames_per_second if reference is not None else float("nan")
    peak_gib = max(r.peak_rss_bytes for r in collected) / 2**30
    mb_per_frame = sum(r.log_bytes for r in collected) / ours.frames / 1e6
    stages = stage_table(ours)
    print(f"renderer: {collected[0].renderer}; workers: {args.workers}")
    print(f"ours      {ours_fps:6.2f} frames/s  ({ours.frames} frames in {ours_wall:.1f} s)")
    if reference is not None:
        print(
            f"reference {reference_fps:6.2f} frames/s  (one process, TinyRenderer, "
            f"{reference.frames} frames)"
        )
        print(f"ratio     {ours_fps / reference_fps:6.2f}x")
    if kinds and plain is not None:
        print(
            f"without labels {plain_fps:6.2f} frames/s (reference), with {','.join(kinds)} at "
            f"1/{args.label_scale} resolution {ours_fps:6.2f}: {100 * (plain_fps / ours_fps - 1):.1f}% "
            f"slower; log {plain_mb:.2f} -> {sum(r.log_bytes for r in collected) / ours.frames / 1e6:.2f} MB per frame"
        )
    if (args.lidar != "raycast" or args.post_process != "cpu") and plain is not None:
        plain_stages = stage_table(plain)
        print(
            f"reference (ray-cast LiDAR, CPU post-processing) {plain_fps:6.2f} frames/s; "
            f"{args.lidar} LiDAR, {args.post_process} post-processing {ours_fps:6.2f} frames/s: "
            f"{ours_fps / plain_fps:.2f}x"
        )
        for stage in ("lidar", "post_process", "jpeg"):
            print(f"  {stage:<13} {plain_stages[stage]:7.1f} -> {stages[stage]:7.1f} ms a frame")
    print("per frame, ms (summed over workers):")
    for stage, milliseconds in stages.items():
        print(f"  {stage:<13} {milliseconds:7.1f}")
    print(f"peak memory per worker: {peak_gib:.2f} GiB")
    print(f"log size: {mb_per_frame:.2f} MB per frame")
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "frames_per_second": ours_fps,
                    "reference_frames_per_second": reference_fps,
                    "plain_suite_frames_per_second": plain_fps,
                    "stages_ms_per_frame": stages,
                    "peak_gib_per_worker": peak_gib,
                    "mb_per_frame": mb_per_frame,
                },
                indent=1,
            )
        )


def mix(args: argparse.Namespace) -> None:
    """The real mix through the CLI's planning; see the module docstring."""
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder) / "data"
        if args.data is not None:
            copy_scenarios(args.data, root)
        else:
            synth = ["synth", "--out", str(root), "--clips", str(args.clips)]
            with contextlib.redirect_stdout(io.StringIO()):
                cli_main([*synth, "--seed", str(args.seed)])
        argv = ["collect", str(root), "--workers", args.workers or "auto", "--gpus", args.gpus]
        argv += ["--sensor-hz", args.sensor_hz]
        if args.max_frames:
            argv += ["--max-frames", str(args.max_frames)]
        parsed = build_parser().parse_args(argv)
        # as `drivee2e collect` does, though that starts the pool's server sooner still, before
        # its own imports (`drivee2e_data.launch`): here it gets the host's probe as a head start
        start_pool_server(parsed)
        planned = plan_collect(parsed)
        if planned.host is not None:
            print(planned.host.describe())
        start = time.perf_counter()
        summary = collect(root, planned.options, planned.workers, gpus=planned.gpus)
        wall = time.perf_counter() - start
        failed = summary.of("failed")
        if failed:
            raise SystemExit(f"collection failed: {failed[0].scenario_id}: {failed[0].error}")
        valid = sum(validate(log_path(root, r.scenario_id)) > 0 for r in summary.results)
        clips = {r.scenario_id: r for r in summary.results}
        conditions = {s: store.read_scenario(root, s, require_map=False).conditions for s in clips}
        identical = _identical(root, Path(folder), planned.options, summary, args.identical)
    work = sum(r.seconds for r in summary.results)
    even = work / summary.workers
    frames = summary.frames
    print(
        f"real mix: {len(clips)} clips of {args.data or f'synth --seed {args.seed}'}, "
        f"{'whole' if not args.max_frames else f'{args.max_frames} frames a clip'}; "
        f"renderer {summary.results[0].renderer}, {planned.options.lidar} LiDAR, "
        f"{summary.workers} workers{f' on GPUs {planned.gpus}' if planned.gpus else ''}, "
        f"sensors at {planned.options.sensor_hz} Hz"
    )
    print(f"collected {frames / wall:6.2f} frames/s ({frames} frames in {wall:.1f} s)")
    print(
        f"summed work {work:.1f} s / {summary.workers} workers = {even:.1f} s; wall / that = "
        f"{wall / even:.2f} (straggler share {100 * (1 - even / wall):.0f}% of the wall time)"
    )
    print(f"logs valid: {valid} of {len(clips)}")
    lost = wall_breakdown(summary, wall)
    print("workers' wall time (s a worker): " + ", ".join(f"{k} {v:.1f}" for k, v in lost.items()))
    if args.timeline:
        try:
            draw_timeline(summary, conditions, args.timeline)
            print(f"timeline: {args.timeline}")
        except ImportError:
            print("timeline: needs matplotlib (the viz extra); --json keeps the spans")
    if args.identical:
        print(f"byte-identical to a one-worker run: {identical} of {args.identical} clips")
    rows = _condition_rows(summary, conditions)
    print("ms a frame, summed over stages of all workers, by condition:")
    columns = JOB_STAGES
    print(f"  {'weather':<9}{'time':<14}{'clips':>5}{'frames':>7}" + "".join(
        f"{c[:8]:>9}" for c in columns) + f"{'total':>9}{'x clear':>9}")  # fmt: skip
    clear = _clear_day(rows)
    for (weather, time_of_day), row in sorted(rows.items(), key=lambda kv: -kv[1]["total"]):
        ratio = row["total"] / rows[clear]["total"] if clear else float("nan")
        print(f"  {weather:<9}{time_of_day:<14}{row['clips']:>5}{row['frames']:>7}" + "".join(
            f"{row[c]:9.1f}" for c in columns) + f"{row['total']:9.1f}{ratio:9.2f}")  # fmt: skip
    slowest = max(rows, key=lambda k: rows[k]["total"])
    if clear:
        print(
            f"slowest condition {'/'.join(slowest)} {rows[slowest]['total']:.0f} ms a frame, "
            f"{rows[slowest]['total'] / rows[clear]['total']:.2f}x the clear-day "
            f"{'/'.join(clear)} {rows[clear]['total']:.0f}"
        )
    peak_gib = max(r.peak_rss_bytes for r in summary.results) / 2**30
    mb = sum(r.log_bytes for r in summary.results) / frames / 1e6
    print(f"peak memory per worker: {peak_gib:.2f} GiB; log size: {mb:.2f} MB per frame")
    if args.json:
        args.json.write_text(json.dumps({
            "frames_per_second": frames / wall, "frames": frames, "wall_s": wall,
            "summed_work_s": work, "workers": summary.workers, "gpus": list(planned.gpus),
            "wall_over_even": wall / even, "valid_logs": valid, "clips": len(clips),
            "identical": identical, "peak_gib_per_worker": peak_gib, "mb_per_frame": mb,
            "conditions": {"/".join(k): v for k, v in rows.items()}, "wall_breakdown": lost,
            "started": summary.started, "spans": {r.scenario_id: r.spans for r in summary.results},
        }, indent=1))  # fmt: skip


def copy_scenarios(source: Path, root: Path) -> None:
    """`source`'s clips and maps (everything but its logs) copied to `root`, so that a set made
    once is collected afresh by every run of this script."""
    if not (source / "scenarios").is_dir():
        raise SystemExit(
            f"--data {source}: no scenarios/ folder (expected a `drivee2e synth` root)"
        )
    shutil.copytree(source, root, ignore=shutil.ignore_patterns("logs"))


def wall_breakdown(summary: CollectSummary, wall: float) -> dict[str, float]:
    """Each worker's share of the wall time, averaged over workers: `start` before its first job,
    its jobs (`setups`: how many, `setup`: their worlds' set-up, `frames`: the rest; logs are
    written from segments by the parent), `gaps` between its jobs, `tail` after its last job
    until the last job of the run ended, and `end` (the index and the rest) after that."""
    per_worker: dict[int, list[tuple[float, float, float]]] = {}
    for result in summary.results:
        for began, ended, pid, setup, *_ in result.spans:
            per_worker.setdefault(pid, []).append((began, ended, setup))
    if not per_worker:
        return {}
    last = max(e for spans in per_worker.values() for _, e, _ in spans)
    totals = dict.fromkeys(("start", "setups", "setup", "frames", "gaps", "tail"), 0.0)
    for spans in per_worker.values():
        spans.sort()
        totals["start"] += spans[0][0] - summary.started
        totals["setups"] += len(spans)
        totals["setup"] += sum(setup for _, _, setup in spans)
        totals["frames"] += sum(e - b - setup for b, e, setup in spans)
        totals["gaps"] += sum(b2 - e1 for (_, e1, _), (b2, _, _) in itertools.pairwise(spans))
        totals["tail"] += last - spans[-1][1]
    shares = {k: v / len(per_worker) for k, v in totals.items()}
    shares["end"] = summary.started + wall - last
    shares["index"] = summary.index_seconds
    return shares


def draw_timeline(summary: CollectSummary, conditions: dict, path: Path) -> None:
    """Every unit on its worker's row, coloured by its clip's weather, its world's set-up
    hatched."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows: dict[int, int] = {}
    colours = {"clear": "#f2c14e", "cloudy": "#9ab0c4", "overcast": "#6c7a89", "wet": "#4f9d8f",
               "rain": "#2f5d9e", "fog": "#c9c3b8"}  # fmt: skip
    figure, axes = plt.subplots(figsize=(11, 0.3 * 16 + 1.5))
    for result in summary.results:
        weather = conditions[result.scenario_id].weather.value
        for began, ended, pid, setup, *_ in sorted(result.spans):
            row = rows.setdefault(pid, len(rows))
            axes.barh(row, ended - began, left=began - summary.started, height=0.8,
                      color=colours.get(weather, "#888888"), edgecolor="black",
                      linewidth=0.3)  # fmt: skip
            axes.barh(
                row,
                setup,
                left=began - summary.started,
                height=0.8,
                color="none",
                hatch="////",
                edgecolor="black",
                linewidth=0,
            )  # the world's set-up
    axes.axvline(summary.wall_seconds, color="red", linewidth=1)
    axes.set_xlim(0, 1.02 * summary.wall_seconds)
    axes.set_xlabel("seconds since the run began (red: the run's end, after the index)")
    axes.set_ylabel("worker")
    axes.set_yticks(range(len(rows)))
    handles = [plt.Rectangle((0, 0), 1, 1, color=c) for c in colours.values()]
    axes.legend(handles, list(colours), ncol=6, loc="upper center", bbox_to_anchor=(0.5, 1.12))
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def _condition_rows(summary: CollectSummary, conditions: dict) -> dict[tuple[str, str], dict]:
    rows: dict[tuple[str, str], dict] = {}
    for result in summary.results:
        condition = conditions[result.scenario_id]
        key = (condition.weather.value, condition.time_of_day.value)
        row = rows.setdefault(key, {"clips": 0, "frames": 0, "seconds": {}})
        row["clips"] += 1
        row["frames"] += result.frames
        for stage, seconds in result.stage_seconds.items():
            row["seconds"][stage] = row["seconds"].get(stage, 0.0) + seconds
    for row in rows.values():
        for stage in JOB_STAGES:
            row[stage] = 1000 * row["seconds"].get(stage, 0.0) / row["frames"]
        # a frame's own cost: set-ups depend on how the plan cut the clip, not on its conditions
        row["total"] = sum(row[stage] for stage in FRAME_STAGES)
        del row["seconds"]
    return rows


def _clear_day(rows: dict[tuple[str, str], dict]) -> tuple[str, str] | None:
    """The clear clip by day (noon first) the others are compared with."""
    for time_of_day in ("noon", "afternoon", "early_morning"):
        if ("clear", time_of_day) in rows:
            return ("clear", time_of_day)
    return None


def _identical(
    root: Path, folder: Path, options: CollectOptions, summary: CollectSummary, count: int
) -> int:
    """How many of the `count` shortest clips one worker collects into the same bytes."""
    shortest = sorted(summary.results, key=lambda r: r.frames)[:count]
    again = folder / "alone"
    same = 0
    for result in shortest:
        scenario = store.read_scenario(root, result.scenario_id)
        store.write_map(again, store.read_map(root, scenario.map_id))
        store.write_scenario(again, scenario)
        collect(again, options, workers=1, only=[result.scenario_id])
        alone = log_path(again, result.scenario_id).read_bytes()
        same += alone == log_path(root, result.scenario_id).read_bytes()
    return same


if __name__ == "__main__":
    main()
