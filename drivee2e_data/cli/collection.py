"""Expert data: `collect`, `logs`, `view` (one frame's views) and `mesa` (the CPU's GL driver)."""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from drivee2e_data import store
from drivee2e_data.cli.arguments import (
    _label_kinds,
    _positive,
    _print_table,
    _size,
    _workers,
)
from drivee2e_data.collect import host as collect_host
from drivee2e_data.collect import runner as collect_runner
from drivee2e_data.collect.job import CollectOptions
from drivee2e_data.collect.preload import start_worker_server
from drivee2e_data.collect.runner import BACKENDS
from drivee2e_data.errors import DriveE2EError, LogFormatError
from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.pipeline import write_view
from drivee2e_data.scenario import TimeOfDay, Weather
from drivee2e_data.sensors.camera_gpu import POST_PROCESS_DEVICES
from drivee2e_data.sensors.camera_gpu import check_device as check_post_process_device
from drivee2e_data.sensors.camera_labels import DEFAULT_LABEL_SCALE
from drivee2e_data.sensors.suite import LIDAR_METHODS
from drivee2e_data.sim import egl_devices, gl_context, mesa, mesa_fetch
from drivee2e_data.sim.world import RENDERERS


def add_view(commands) -> None:  # type: ignore[no-untyped-def]
    """The `view` command's arguments."""
    view = commands.add_parser("view", help="contact sheet of one frame: six views and a top view")
    view.add_argument("data", type=Path, help="data root")
    view.add_argument("scenario_id")
    view.add_argument("--frame", type=int, default=0)
    view.add_argument("--out", type=Path, required=True, help="PNG to write")
    view.add_argument("--renderer", choices=RENDERERS, default="auto")
    view.add_argument(
        "--weather", choices=[w.value for w in Weather], help="view under another weather"
    )
    view.add_argument(
        "--time-of-day", choices=[t.value for t in TimeOfDay], help="...or another time"
    )


def add_collect(commands) -> None:  # type: ignore[no-untyped-def]
    """The `collect` command's arguments."""
    collect = commands.add_parser(
        "collect", help="drive every clip's ego with the sensor suite; one MCAP log per clip"
    )
    collect.add_argument("data", type=Path, help="data root (curated: every clip needs an ego)")
    collect.add_argument(
        "--workers", type=_workers, default=1,
        help="processes, or 'auto': the host's cores, at most one per 25 frames and 1.5 GiB "
        "each (default 1); with more than one, clips are cut into segments any worker takes",
    )  # fmt: skip
    collect.add_argument(
        "--gpus", type=_gpus, default=None, metavar="all|I,J",
        help="EGL GPU devices the workers' GL renderers share, round robin (default: all)",
    )  # fmt: skip
    collect.add_argument("--backend", choices=BACKENDS, default="local")
    collect.add_argument(
        "--renderer", choices=RENDERERS, default="auto",
        help="gl: OpenGL through moderngl (the default where a context can be made); egl, tiny: "
        "pybullet's own renderers",
    )  # fmt: skip
    collect.add_argument(
        "--cameras", nargs="+", choices=topics.CAMERAS, default=None, help="default: all six"
    )
    collect.add_argument(
        "--image-size", type=_size, default=None, metavar="WxH", help="default 1600x900"
    )
    collect.add_argument("--jpeg-quality", type=int, default=85, choices=range(1, 101), metavar="Q")
    collect.add_argument(
        "--max-frames", type=_positive, default=None, help="only the first N frames of each clip"
    )
    collect.add_argument("--only", nargs="+", default=None, metavar="ID", help="these clips only")
    collect.add_argument(
        "--camera-labels", type=_label_kinds, default=(), metavar="KINDS",
        help="also dense labels per camera, comma-separated: depth,semantic,instance",
    )  # fmt: skip
    collect.add_argument(
        "--label-scale", type=_positive, default=DEFAULT_LABEL_SCALE,
        help=f"labels at 1/N of the camera resolution (default {DEFAULT_LABEL_SCALE})",
    )  # fmt: skip
    collect.add_argument(
        "--lidar", choices=LIDAR_METHODS, default=None,
        help="LiDAR by ray casting (the reference) or read from depth images rendered at the "
        "LiDAR (agrees with ray casting; a sweep 5.9x faster on llvmpipe with the GL renderer); "
        "default: depth where an OpenGL renderer works (gl or egl), else raycast",
    )  # fmt: skip
    collect.add_argument(
        "--sensor-hz", type=int, choices=topics.SENSOR_RATES_HZ, default=10,
        help="render and log the sensors (and boxes) at this rate; the ego's pose, IMU, GNSS and "
        "the lights stay at 10 Hz (2: nuScenes' keyframes, about 5x less work; default 10)",
    )  # fmt: skip
    collect.add_argument(
        "--post-process", choices=POST_PROCESS_DEVICES, default="cpu",
        help="where camera images get their weather, resize and JPEG: cpu (OpenCV; default) "
        "or cuda (torch and nvJPEG, images within 2 levels of the CPU's before JPEG; slower "
        "with many workers sharing one GPU, see docs/benchmarks.md)",
    )  # fmt: skip


def add_logs(commands) -> None:  # type: ignore[no-untyped-def]
    """The `logs` command's arguments."""
    logs = commands.add_parser("logs", help="list and validate the MCAP logs of a data root")
    logs.add_argument("data", type=Path, help="data root")
    logs.add_argument("--validate", action="store_true", help="check every topic at every frame")


def add_mesa(commands) -> None:  # type: ignore[no-untyped-def]
    """The `mesa` command's arguments."""
    command = commands.add_parser(
        "mesa", help="which Mesa draws on a CPU; --fetch puts Mesa 25 (faster llvmpipe) in place"
    )
    command.add_argument("--fetch", action="store_true",
                         help=f"fetch Mesa's EGL libraries from Debian's {mesa_fetch.SUITE}")  # fmt: skip
    command.add_argument("--folder", type=Path, default=None,
                         help=f"where (default: where {mesa.MESA_VARIABLE} names, else "
                              f"{mesa.default_folder()}, where drivee2e finds it)")  # fmt: skip
    command.add_argument("--mirror", default=mesa_fetch.MIRROR, help="Debian mirror")


def run_mesa(args: argparse.Namespace) -> int:
    if args.fetch:
        folder = args.folder or mesa.chosen_folder()
        reason = mesa.why_not(folder)
        if reason is not None or folder is None:
            raise DriveE2EError(f"Mesa not fetched: it would not be used here ({reason})")
        found, renderer = mesa_fetch.fetch(folder, mirror=args.mirror)
        print(f"Mesa {found.version} in {found.folder}: {renderer}")
        chosen = mesa.chosen_folder()
        if chosen is None or chosen.resolve() != found.folder.resolve():
            print(f"export {mesa.MESA_VARIABLE}={found.folder.resolve()}  # to use it")
        return 0
    print(mesa.describe())
    if gl_context.gl_available():
        print(f"drawn by: {gl_context.gl_driver()}")
    else:
        print("OpenGL: no context can be made here (moderngl over EGL)")
    return 0


def run_view(args: argparse.Namespace) -> int:
    write_view(
        args.data,
        args.scenario_id,
        args.frame,
        args.out,
        args.renderer,
        args.weather,
        args.time_of_day,
    )
    print(f"wrote {args.out}")
    return 0


def _gpus(text: str) -> tuple[int, ...] | None:
    try:
        return egl_devices.parse_gpus(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _chosen_gpus(wanted: tuple[int, ...] | None) -> tuple[int, ...]:
    """The EGL GPU devices to spread the workers over: all found, or those asked for (each
    must be one)."""
    found = egl_devices.gpu_devices()
    if wanted is None:
        return found
    missing = [d for d in wanted if d not in found]
    if missing:
        have = ", ".join(map(str, found)) or "none"
        raise DriveE2EError(f"--gpus: EGL device {missing[0]} is not a GPU here (GPUs: {have})")
    return wanted


@dataclass(frozen=True)
class CollectPlan:
    """What `drivee2e collect`'s arguments come to on this host."""

    options: CollectOptions
    workers: int
    gpus: tuple[int, ...]
    host: collect_host.HostPlan | None  # when the host chose the workers or the LiDAR


def plan_collect(args: argparse.Namespace) -> CollectPlan:
    """Options, workers and GPUs from `collect`'s arguments (the host's plan where asked for);
    `scripts/dev/bench_collect.py` runs the same."""
    scenario_ids = args.only or store.scenario_ids(args.data)
    workers, lidar, post_process = args.workers, args.lidar, args.post_process
    check_post_process_device(post_process)  # before any clip starts
    gpus = _chosen_gpus(args.gpus)
    host = None
    if workers == "auto" or lidar is None:  # the host decides (an EGL probe, once)
        frames = sum(
            collect_runner.frames_to_collect(args.data, s, args.max_frames) or 0
            for s in scenario_ids
        )
        host = collect_host.plan(
            frames,
            renderer=args.renderer,
            gpus=len(gpus),
            sensor_every=topics.sensor_every(args.sensor_hz),
        )
        if workers == "auto":
            workers = host.workers
        else:  # the host chose the LiDAR only; the line printed says the workers given
            host = host.given(workers)
        lidar = lidar or host.lidar
    options = CollectOptions(
        renderer=args.renderer,
        cameras=tuple(args.cameras) if args.cameras else None,
        image_size=args.image_size,
        jpeg_quality=args.jpeg_quality,
        max_frames=args.max_frames,
        camera_labels=args.camera_labels,
        label_scale=args.label_scale,
        lidar=lidar,
        post_process=post_process,
        sensor_hz=args.sensor_hz,
    )
    return CollectPlan(options, workers, gpus, host if scenario_ids else None)


def start_pool_server(args: argparse.Namespace) -> None:
    """Start the server a local pool's workers fork from before the host is probed, so that
    its imports run meanwhile (the `drivee2e` command started it sooner still: `launch`)."""
    if args.workers != 1 and args.backend == "local":
        start_worker_server()


def run_collect(args: argparse.Namespace) -> int:
    start_pool_server(args)
    planned = plan_collect(args)
    options, workers, gpus = planned.options, planned.workers, planned.gpus
    if planned.host is not None:
        print(planned.host.describe(), file=sys.stderr)
    bars: list[tqdm] = []

    def progress(total: int, clips: int):  # type: ignore[no-untyped-def]
        bars.append(tqdm(total=total, unit="frame", desc=f"collecting {clips} clips", disable=None))
        return bars[0].update

    try:
        summary = collect_runner.collect(
            args.data, options, workers, args.backend, args.only, progress, gpus
        )
    finally:
        for bar in bars:
            bar.close()
    collected, skipped, failed = (summary.of(s) for s in ("collected", "skipped", "failed"))
    egoless = [r.scenario_id for r in summary.of("no ego")]
    if egoless:
        more = f" and {len(egoless) - 10} more" if len(egoless) > 10 else ""
        print(f"{len(egoless)} clips skipped, no ego to mount the rig on (drivee2e curate chooses "
              f"one where a vehicle is seen throughout): {', '.join(egoless[:10])}{more}")  # fmt: skip
    print(
        f"{len(collected)} clips collected, {len(skipped)} already done, {len(failed)} failed; "
        f"{summary.frames} frames in {summary.wall_seconds:.0f} s "
        f"({summary.frames_per_second:.2f} frames/s); logs {summary.log_bytes / 1e9:.2f} GB "
        f"under {args.data / 'logs'}; index {summary.index_rows} frames"
    )
    renderers = sorted({r.renderer for r in collected if r.renderer})
    if renderers:
        on = f" on {len(gpus)} GPUs" if len(gpus) > 1 else ""
        print(
            f"renderer: {', '.join(renderers)}; LiDAR: {options.lidar}; camera post-processing: "
            f"{options.post_process}; workers: {summary.workers}{on}"
        )
    nodes = summary.node_frames
    if nodes:
        shares = ", ".join(f"{node[:8]} {frames}" for node, frames in sorted(nodes.items()))
        print(f"frames on each of {len(nodes)} Ray nodes: {shares}")
    for result in failed:
        print(f"failed: {result.scenario_id}: {result.error}", file=sys.stderr)
    return 1 if failed else 0


def run_logs(args: argparse.Namespace) -> int:
    paths = sorted((args.data / "logs").glob("*.mcap"))
    if not paths:
        raise DriveE2EError(
            f"{args.data}: no logs under {args.data / 'logs'}; run drivee2e collect"
        )
    rows, bad = [], 0
    for path in paths:
        try:
            with LogReader(path) as log:
                if args.validate:
                    log.validate()
                rows.append(
                    (
                        log.scenario_id,
                        str(log.num_frames),
                        f"{path.stat().st_size / 1e6:.1f}",
                        ",".join(c.removeprefix("CAM_") for c in log.cameras),
                        log.collection.get("renderer", "?"),
                        "valid" if args.validate else "-",
                    )
                )
        except LogFormatError as error:
            bad += 1
            print(f"invalid: {error}", file=sys.stderr)
    _print_table(("log", "frames", "MB", "cameras", "renderer", "check"), rows)
    print(f"{len(rows)} logs" + (f", {bad} invalid" if bad else ""))
    return 1 if bad else 0
