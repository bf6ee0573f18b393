"""The `drivee2e` command: parses arguments, calls the library, prints. No logic of its own."""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

from tqdm import tqdm

from drivee2e_data import __version__, figures, openloop, pipeline, splits, store
from drivee2e_data.agents import admlp, camera, registry
from drivee2e_data.agents.constant_velocity import ConstantVelocity
from drivee2e_data.agents.registry import AGENTS
from drivee2e_data.agents.training import TrainOptions
from drivee2e_data.collect import host as collect_host
from drivee2e_data.collect import runner as collect_runner
from drivee2e_data.collect.job import CollectOptions
from drivee2e_data.collect.runner import BACKENDS
from drivee2e_data.curation.occlusion import Variant
from drivee2e_data.errors import DriveE2EError, LogFormatError
from drivee2e_data.evaluate import runner, variants
from drivee2e_data.export.infos import export_infos
from drivee2e_data.export.nuscenes import export_nuscenes
from drivee2e_data.loaders.dataset import DriveE2EDataset
from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.metrics.openloop import CONVENTIONS
from drivee2e_data.pipeline import write_view
from drivee2e_data.scenario import AgentClass, TimeOfDay, Weather
from drivee2e_data.sensors.camera_gpu import POST_PROCESS_DEVICES
from drivee2e_data.sensors.camera_gpu import check_device as check_post_process_device
from drivee2e_data.sensors.camera_labels import DEFAULT_LABEL_SCALE, LABEL_KINDS
from drivee2e_data.sensors.suite import LIDAR_METHODS
from drivee2e_data.sim.world import RENDERERS
from drivee2e_data.sources.cutting import CUT_MODES

PLANNERS = ("constant-velocity", "admlp", "camera")
CLASS_ABBREVIATION = {
    AgentClass.CAR: "car",
    AgentClass.VAN: "van",
    AgentClass.TRUCK: "trk",
    AgentClass.BUS: "bus",
    AgentClass.PEDESTRIAN: "ped",
    AgentClass.CYCLIST: "cyc",
    AgentClass.TRICYCLIST: "tri",
    AgentClass.MOTORCYCLIST: "mot",
}


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _workers(text: str) -> int | str:
    return "auto" if text == "auto" else _positive(text)


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return value


def _label_kinds(text: str) -> tuple[str, ...]:
    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    unknown = [k for k in kinds if k not in LABEL_KINDS]
    if unknown or not kinds:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected some of {','.join(LABEL_KINDS)}, comma-separated"
        )
    return kinds


def _add_cut_arguments(command: argparse.ArgumentParser) -> None:
    command.add_argument(
        "--cut",
        choices=CUT_MODES,
        default="ego",
        help="how recordings longer than 1.5 clips are cut: a clip per vehicle passing through "
        "the junction (ego, default) or fixed windows",
    )
    command.add_argument(
        "--clip-seconds",
        type=_positive_float,
        default=20.0,
        help="window length for --cut windows (default 20)",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="drivee2e",
        description="Real intersection traffic to simulated expert data and a closed-loop benchmark.",
    )
    parser.add_argument("--version", action="version", version=f"drivee2e-data {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)

    synth = commands.add_parser("synth", help="synthesise intersections and staged clips")
    synth.add_argument("--out", type=Path, required=True, help="data root to write into")
    synth.add_argument("--clips", type=_positive, default=12, help="number of clips (default 12)")
    synth.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    synth.add_argument(
        "--intersections",
        type=_positive,
        default=None,
        help="number of distinct intersections (default: min(clips, 4))",
    )
    synth.add_argument(
        "--workers", type=_positive, default=1, help="processes generating clips (default 1)"
    )
    synth.add_argument(
        "--recording-seconds",
        type=_positive_float,
        default=None,
        help="instead of staged clips: one intersection's traffic this long, no staged ego, "
        "cut into clips as an import would cut it (see --cut)",
    )
    _add_cut_arguments(synth)

    importer = commands.add_parser("import", help="import real traffic and maps")
    importer.add_argument("kind", choices=pipeline.IMPORT_KINDS, help="source format")
    importer.add_argument("source", type=Path, help="file or folder to import")
    importer.add_argument("--out", type=Path, required=True, help="data root to write into")
    importer.add_argument(
        "--keep-egoless", action="store_true",
        help="also write clips with no motor vehicle (no ego can be chosen; nothing collects them)",
    )  # fmt: skip
    _add_cut_arguments(importer)

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

    curate = commands.add_parser("curate", help="score tracks, choose egos, label behaviours")
    curate.add_argument("data", type=Path, help="data root")
    curate.add_argument(
        "--occlusion",
        choices=("vehicle", "all"),
        default=None,
        help="instead: write the occlusion variant (agents never seen by the ego's cameras in "
        "the collected logs removed: vehicles only, or every class) to DATA/variants/",
    )

    scenarios = commands.add_parser(
        "scenarios", help="list and validate the scenarios of a data root"
    )
    scenarios.add_argument("data", type=Path, help="data root")
    scenarios.add_argument("--stats", action="store_true", help="print the dataset's distributions")
    scenarios.add_argument(
        "--plot", type=Path, default=None, help="draw the distributions to this PNG"
    )
    collect = commands.add_parser(
        "collect", help="drive every clip's ego with the sensor suite; one MCAP log per clip"
    )
    collect.add_argument("data", type=Path, help="data root (curated: every clip needs an ego)")
    collect.add_argument(
        "--workers", type=_workers, default=1,
        help="processes, or 'auto': the host's cores, at most one per clip and 1.5 GiB each "
        "(default 1)",
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
        "--post-process", choices=POST_PROCESS_DEVICES, default="cpu",
        help="where camera images get their weather, resize and JPEG: cpu (OpenCV; default) "
        "or cuda (torch and nvJPEG, images within 2 levels of the CPU's before JPEG; slower "
        "with many workers sharing one GPU, see docs/benchmarks.md)",
    )  # fmt: skip

    split = commands.add_parser(
        "split", help="2:1:1 train/val/test over whole clips, stratified by behaviour"
    )
    split.add_argument("data", type=Path, help="data root")
    split.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    split.add_argument(
        "--name", default="default", help="manifest name: DATA/splits/NAME.csv (default: default)"
    )

    train = commands.add_parser("train", help="train a baseline planner on a split")
    train.add_argument("model", choices=("admlp", "camera"), help="which baseline")
    train.add_argument("data", type=Path, help="data root (collected, split)")
    _split_options(train, "train")
    train.add_argument("--out", type=Path, required=True, help="checkpoint to write (resumes)")
    train.add_argument(
        "--epochs", type=_positive, default=None, help="default: admlp 60, camera 40"
    )
    train.add_argument(
        "--batch-size", type=_positive, default=None, help="default: admlp 64, camera 32"
    )
    train.add_argument("--learning-rate", type=float, default=1e-3)
    train.add_argument("--seed", type=int, default=0)

    predict = commands.add_parser(
        "predict", help="a baseline's plans for every sample of a split (predictions file)"
    )
    predict.add_argument("data", type=Path, help="data root")
    _split_options(predict, "val")
    predict.add_argument("--model", choices=PLANNERS, required=True)
    predict.add_argument("--checkpoint", type=Path, help="the model's checkpoint (admlp)")
    predict.add_argument("--out", type=Path, required=True, help="predictions Parquet to write")

    openloop = commands.add_parser(
        "openloop", help="score a predictions file: L2 and collision rate, per category"
    )
    openloop.add_argument("data", type=Path, help="data root")
    _split_options(openloop, "val")
    openloop.add_argument(
        "--predictions", type=Path, required=True, help="Parquet (docs/loaders.md)"
    )
    openloop.add_argument("--convention", choices=CONVENTIONS, default="stp3")
    openloop.add_argument("--json", type=Path, default=None, help="also save the table as JSON")

    export = commands.add_parser("export", help="write the nuScenes layout or VAD info pickles")
    export.add_argument("format", choices=("nuscenes", "infos"))
    export.add_argument("data", type=Path, help="data root (collected)")
    export.add_argument(
        "--out", type=Path, required=True, help="nuscenes: a new folder; infos: the .pkl to write"
    )
    export.add_argument("--version", dest="table_version", default="v1.0-drivee2e")
    export.add_argument("--split", choices=(*splits.SPLITS, "all"), default="all")
    export.add_argument("--split-name", default="default", help="DATA/splits/NAME.csv, or a .csv")
    export.add_argument(
        "--keyframe-every", type=_positive, default=5, help="frames per sample (5: 2 Hz)"
    )
    export.add_argument(
        "--nuscenes", type=Path, default=None, help="infos: the nuscenes export the paths name"
    )

    evaluate = commands.add_parser(
        "evaluate", help="closed loop: drive each clip of a split with an agent; SR and DS"
    )
    evaluate.add_argument("data", type=Path, help="data root (curated; logs for --variant)")
    _split_options(evaluate, "val")
    evaluate.add_argument(
        "--agent", default="expert", help=f"{', '.join(AGENTS)}, or MODULE:CLASS (default expert)"
    )
    evaluate.add_argument(
        "--agent-cmd", default=None, metavar="CMD", help="run the agent as this child process "
        "(its own environment; protocol in drivee2e_data/evaluate/agent_client.py)",
    )  # fmt: skip
    evaluate.add_argument("--checkpoint", type=Path, default=None, help="the agent's checkpoint")
    evaluate.add_argument(
        "--reactive", action="store_true", help="vehicles follow their paths with IDM"
    )
    evaluate.add_argument("--variant", choices=[v.value for v in Variant], default="complete")
    evaluate.add_argument(
        "--min-speed",
        action="store_true",
        help="apply LB2's minimum-speed penalty (off by default)",
    )
    evaluate.add_argument("--workers", type=_positive, default=1, help="processes (default 1)")
    evaluate.add_argument("--record", action="store_true", help="write RUN/records/<clip>.mcap")
    evaluate.add_argument("--seed", type=int, default=0)
    evaluate.add_argument("--renderer", choices=RENDERERS, default="auto")
    evaluate.add_argument(
        "--step-timeout",
        type=float,
        default=30.0,
        help="seconds an --agent-cmd child may take a step",
    )
    evaluate.add_argument(
        "--out",
        type=Path,
        default=None,
        help="run folder (default DATA/results/AGENT-SPLIT-VARIANT)",
    )
    evaluate.add_argument("--only", nargs="+", default=None, metavar="ID", help="these clips only")

    logs = commands.add_parser("logs", help="list and validate the MCAP logs of a data root")
    logs.add_argument("data", type=Path, help="data root")
    logs.add_argument("--validate", action="store_true", help="check every topic at every frame")
    return parser


def _split_options(parser: argparse.ArgumentParser, default: str) -> None:
    parser.add_argument("--split", choices=(*splits.SPLITS, "all"), default=default)
    parser.add_argument(
        "--split-name", default="default", help="DATA/splits/NAME.csv, or a .csv path"
    )


def _labels_only(args: argparse.Namespace) -> DriveE2EDataset:
    """The split's samples without sensor data or map labels: what planners of the ego's
    state and the metrics read (map labels would be computed for every sample and never read)."""
    return DriveE2EDataset(args.data, args.split, args.split_name, cameras=(), with_map=False)


def _train(args: argparse.Namespace) -> int:
    epochs = args.epochs or (60 if args.model == "admlp" else 40)
    batch_size = args.batch_size or (64 if args.model == "admlp" else 32)
    options = TrainOptions(epochs, batch_size, args.learning_rate, args.seed)
    if args.model == "camera":
        dataset, trainer = camera.dataset_for(args.data, args.split, args.split_name), camera.train
    else:
        dataset, trainer = _labels_only(args), admlp.train
    with (
        tqdm(total=len(dataset), unit="sample", desc="reading", disable=None) as reading,
        tqdm(total=epochs, unit="epoch", desc=f"training {args.model}", disable=None) as bar,
    ):

        def on_epoch(epoch: int, loss: float) -> None:
            bar.n = epoch
            bar.set_postfix(loss=f"{loss:.3f}")
            bar.refresh()

        saved = trainer(dataset, args.out, options, on_epoch, reading.update)
    print(
        f"{args.model}: {saved['samples']} samples, {saved['epoch']} epochs, final L1 loss "
        f"{saved['losses'][-1]:.3f} m; wrote {args.out}"
    )
    return 0


def _planner(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    if args.model in ("admlp", "camera"):
        if args.checkpoint is None:
            raise DriveE2EError(
                f"--model {args.model} needs --checkpoint (drivee2e train {args.model} writes one)"
            )
        return (
            admlp.load(args.checkpoint)
            if args.model == "admlp"
            else camera.CameraPlanner(args.checkpoint)
        )
    return ConstantVelocity()


def _predict(args: argparse.Namespace) -> int:
    planner = _planner(args)
    if args.model == "camera":
        dataset = camera.dataset_for(args.data, args.split, args.split_name)
    else:
        dataset = _labels_only(args)
    with tqdm(
        total=len(dataset), unit="sample", desc=f"planning ({args.model})", disable=None
    ) as bar:
        table = openloop.predict(dataset, planner, bar.update)
    openloop.write_predictions(args.out, table)
    print(f"wrote {args.out}: {table.num_rows} plans for split {args.split}")
    return 0


def _openloop(args: argparse.Namespace) -> int:
    dataset = _labels_only(args)
    plans = openloop.read_predictions(args.predictions, dataset)
    with tqdm(total=len(plans), unit="sample", desc="scoring", disable=None) as bar:
        results = openloop.score(dataset, plans, args.convention, bar.update)
    keys = (
        "l2_1s",
        "l2_2s",
        "l2_3s",
        "l2_avg",
        "collision_1s",
        "collision_2s",
        "collision_3s",
        "collision_avg",
    )
    header = ("category", "samples", *(k.replace("collision", "col") for k in keys))
    rows = [
        (name, str(values["samples"]), *(_cell(values.get(k), k) for k in keys))
        for name, values in results.items()
    ]
    print(
        f"open-loop, {args.convention} convention, split {args.split}: {len(plans)} of {len(dataset)} samples planned"
    )
    _print_table(header, rows)
    if args.json is not None:
        document = {"convention": args.convention, "split": args.split, "results": results}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        store.write_bytes_atomic(args.json, json.dumps(document, indent=2).encode())
        print(f"wrote {args.json}")
    return 0


def _export(args: argparse.Namespace) -> int:
    with tqdm(unit="sample", desc=f"exporting {args.format}", disable=None) as bar:
        if args.format == "nuscenes":
            summary = export_nuscenes(
                args.data,
                args.out,
                args.table_version,
                args.split,
                args.split_name,
                args.keyframe_every,
                bar.update,
            )
            message = (
                f"wrote {summary.out}: {summary.scenes} scenes, {summary.samples} samples, "
                f"{summary.annotations} annotations ({args.table_version})"
            )
        else:
            if args.nuscenes is None:
                raise DriveE2EError("export infos needs --nuscenes ROOT (drivee2e export nuscenes)")
            count = export_infos(
                args.data,
                args.out,
                args.nuscenes,
                args.table_version,
                args.split,
                args.split_name,
                args.keyframe_every,
                bar.update,
            )
            message = f"wrote {args.out}: {count} infos (split {args.split})"
    print(message)
    return 0


def _cell(value: float | None, key: str) -> str:
    if value is None or value != value:
        return "-"
    return f"{100 * value:.2f}%" if key.startswith("collision") else f"{value:.2f}"


def _size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH such as 1600x900, got {text!r}") from None
    if width < 16 or height < 16:
        raise argparse.ArgumentTypeError(f"image size {text}: expected at least 16x16")
    return width, height


def _collect(args: argparse.Namespace) -> int:
    clips = len(args.only) if args.only else len(store.scenario_ids(args.data))
    workers, lidar, post_process = args.workers, args.lidar, args.post_process
    check_post_process_device(post_process)  # before any clip starts
    if workers == "auto" or lidar is None:  # the host decides (an EGL probe, once)
        host = collect_host.plan(clips, renderer=args.renderer)
        if clips:
            print(host.describe(), file=sys.stderr)
        workers = host.workers if workers == "auto" else workers
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
    )
    bars: list[tqdm] = []

    def progress(total: int, clips: int):  # type: ignore[no-untyped-def]
        bars.append(tqdm(total=total, unit="frame", desc=f"collecting {clips} clips", disable=None))
        return bars[0].update

    try:
        summary = collect_runner.collect(
            args.data, options, workers, args.backend, args.only, progress
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
        print(
            f"renderer: {', '.join(renderers)}; LiDAR: {options.lidar}; camera post-processing: "
            f"{options.post_process}; workers: {workers}"
        )
    for result in failed:
        print(f"failed: {result.scenario_id}: {result.error}", file=sys.stderr)
    return 1 if failed else 0


def _logs(args: argparse.Namespace) -> int:
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


def _synth(args: argparse.Namespace) -> int:
    if args.recording_seconds is not None:
        print(f"simulating {args.recording_seconds:g} s of traffic ...", file=sys.stderr)
        written, cut = pipeline.synthesize_recording(
            args.out, args.seed, args.recording_seconds, args.clip_seconds, args.cut
        )
        with_ego = sum(store.read_scenario(args.out, i).ego_id is not None for i in written)
        print(f"{len(written)} clips ({with_ego} with an ego) written under {args.out}")
        if cut is not None:
            print("\n".join(cut.lines()))
        return 0
    with tqdm(total=args.clips, unit="clip", desc="synthesising", disable=None) as bar:
        report = pipeline.synthesize(
            args.out,
            args.clips,
            args.seed,
            args.intersections,
            on_clip=lambda scenario_id, skipped: bar.update(1),
            workers=args.workers,
        )
    print(
        f"{len(report.written)} clips written, {len(report.skipped)} already present, "
        f"{len(report.maps)} maps, under {args.out}"
    )
    return 0


def _import(args: argparse.Namespace) -> int:
    with tqdm(unit="clip", desc=f"importing {args.kind}", disable=None) as bar:
        summary = pipeline.import_source(
            args.out,
            args.kind,
            args.source,
            args.clip_seconds,
            on_scenario=lambda _: bar.update(1),
            cut=args.cut,
            keep_egoless=args.keep_egoless,
        )
    print(
        f"{len(summary.scenarios)} scenarios and {len(summary.maps)} maps written under {args.out}"
    )
    if summary.egoless:
        everything = "no clip has an ego: all " if not summary.scenarios else ""
        print(f"{everything}{summary.egoless} clips hold no motor vehicle (nothing an ego could "
              "be), not written (--keep-egoless writes them)")  # fmt: skip
    for map_id, plane in summary.grounds.items():
        if plane.source != "flat":
            print(f"{map_id}: ground levelled to z = 0 from its {plane.source} (removed: "
                  f"{plane.height_m:+.2f} m at the origin, slope {plane.slope_x:+.3f} x, "
                  f"{plane.slope_y:+.3f} y, and the road's curvature: {plane.residual_rms_m:.2f} m "
                  f"RMS; what stays is the flat-ground error, {plane.field_rms_m:.2f} m RMS over "
                  f"{plane.points} points)")  # fmt: skip
    for recording, cut in summary.cuts.items():
        print(f"{recording} cut into clips:")
        print("\n".join(cut.lines()))
    lines = summary.report.lines()
    if lines:
        print("per source class:")
        print("\n".join(lines))
    for warning in summary.report.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    if summary.failures:
        print(f"{len(summary.failures)} failed (nothing of them written):", file=sys.stderr)
        for name, error in summary.failures.items():
            print(f"  {name}: {error}", file=sys.stderr)
        return 1
    return 0


def _view(args: argparse.Namespace) -> int:
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


def _curate(args: argparse.Namespace) -> int:
    if not (args.data / "scenarios").is_dir():
        raise DriveE2EError(f"{args.data}: no scenarios/ folder; is this a drivee2e data root?")
    if args.occlusion is not None:
        return _occlusion(args)
    with tqdm(unit="clip", desc="curating", disable=None) as bar:
        rows = pipeline.curate(args.data, on_scenario=lambda _: bar.update(1))
    header = ("scenario", "ego", "ego from", "behaviour", "dropped", "repaired")
    table = [
        (
            r.scenario_id,
            r.ego_id or "-",
            r.ego_source,
            r.behavior,
            str(r.tracks_dropped),
            str(r.tracks_repaired),
        )
        for r in rows
    ]
    _print_table(header, table)
    labelled = sum(r.behavior != "-" for r in rows)
    reasons = Counter(r.ego_source.removeprefix("none: ") for r in rows if r.ego_id is None)
    without = "".join(f"; {n} without an ego: {reason}" for reason, n in reasons.most_common())
    print(f"{len(rows)} clips curated, {labelled} labelled{without}")
    return 0


def _occlusion(args: argparse.Namespace) -> int:
    variant = Variant.OCC_VEHICLE if args.occlusion == "vehicle" else Variant.OCC_ALL
    with tqdm(unit="clip", desc=f"{variant.value} variant", disable=None) as bar:
        path, removed = variants.write_variant(args.data, variant, lambda _: bar.update(1))
    rows = [(clip, str(len(ids))) for clip, ids in sorted(removed.items())]
    _print_table(("scenario", "agents removed"), rows)
    print(
        f"{sum(len(v) for v in removed.values())} agents removed over {len(removed)} clips: {path}"
    )
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    if args.agent_cmd is None:
        registry.build(args.agent, args.checkpoint)  # a bad name or checkpoint fails here, once
    options = runner.EvaluationOptions(
        agent=args.agent,
        checkpoint=str(args.checkpoint) if args.checkpoint else None,
        agent_cmd=args.agent_cmd,
        reactive=args.reactive,
        variant=args.variant,
        min_speed=args.min_speed,
        record=args.record,
        seed=args.seed,
        renderer=args.renderer,
        step_timeout_s=args.step_timeout,
    )
    manifest = splits.split_path(args.data, args.split_name)
    if not manifest.is_file():
        raise DriveE2EError(f"{manifest}: no split manifest; run drivee2e split {args.data}")
    clips = splits.scenario_ids(manifest, args.split)
    if args.only:
        clips = [c for c in clips if c in set(args.only)]
    if not clips:
        raise DriveE2EError(f"{manifest}: split {args.split!r} has no clips to evaluate")
    out = args.out or args.data / runner.RESULTS_FOLDER / runner.run_name(options, args.split)
    with tqdm(total=len(clips), unit="episode", desc="evaluating", disable=None) as bar:
        bar.update(len(clips) - len(runner.prepare_run(args.data, out, options, clips)))

        def done(row: dict) -> None:
            bar.update(1)
            if row.get("status") in ("error", "agent_failed"):
                bar.write(f"{row['scenario_id']}: {row.get('failure', '')}")

        rows = runner.evaluate(args.data, clips, options, out, args.workers, done, registry.build)
    summary = runner.write_results(out, rows, options)
    print(runner.markdown_table(summary), end="")
    print(f"results: {out}/ (episodes.parquet, summary.json, table.md)")
    return 0


def _print_table(header: tuple[str, ...], rows: list[tuple[str, ...]]) -> None:
    widths = [max(len(str(r[k])) for r in [header, *rows]) for k in range(len(header))]
    for row in [header, *rows]:
        cells = (str(cell).ljust(width) for cell, width in zip(row, widths, strict=True))
        print("  ".join(cells).rstrip())


def _scenarios(args: argparse.Namespace) -> int:
    if not (args.data / "scenarios").is_dir():
        raise DriveE2EError(f"{args.data}: no scenarios/ folder; is this a drivee2e data root?")
    with tqdm(unit="scenario", desc="reading", leave=False, disable=None) as bar:
        summaries = pipeline.summarize(args.data, on_scenario=lambda _: bar.update(1))
    header = ("scenario", "map", "dur s", "agents", "ego", "behaviour", "weather", "time of day")
    rows = [
        (
            s.scenario_id,
            s.map_id,
            f"{s.duration_s:.1f}",
            " ".join(f"{CLASS_ABBREVIATION[c]}{n}" for c, n in s.agents.items() if n),
            s.ego_id or "-",
            s.behavior,
            s.weather,
            s.time_of_day,
        )
        for s in summaries
    ]
    _print_table(header, rows)
    print(f"{len(rows)} scenarios")
    if args.stats or args.plot:
        stats = pipeline.statistics(summaries)
        if args.stats:
            for name, counts in stats.items():
                print(f"{name}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
            without = pipeline.clips_without_ego(summaries)
            print(f"clips without an ego: {sum(without.values())}"
                  + "".join(f"; {n}: {why}" for why, n in without.most_common()))  # fmt: skip
        if args.plot:
            figures.plot_statistics(
                stats, args.plot, title=f"{args.data.name}: {len(summaries)} clips"
            )
            print(f"wrote {args.plot}")
    return 0


def _split(args: argparse.Namespace) -> int:
    path, rows = splits.split_root(args.data, args.name, args.seed)
    table = splits.counts_table(rows)
    _print_table(table[0], table[1:])
    print(f"wrote {path}: {len(rows)} clips")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    handlers = {
        "synth": _synth,
        "import": _import,
        "curate": _curate,
        "view": _view,
        "scenarios": _scenarios,
        "collect": _collect,
        "logs": _logs,
        "split": _split,
        "train": _train,
        "predict": _predict,
        "openloop": _openloop,
        "export": _export,
        "evaluate": _evaluate,
    }
    try:
        return handlers[args.command](args)
    except DriveE2EError as error:
        print(f"drivee2e: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("drivee2e: interrupted; finished outputs are kept, rerun to resume", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
