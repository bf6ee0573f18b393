"""Imitation learning on the logs: `cache`, `train`, `predict`, `openloop` (L2 and collisions),
`export`.

torch, Lightning and the models are imported by the commands that run them, not with this
module: every `drivee2e` command, and every collection worker (which re-imports the command's
module), would otherwise pay 3 s for them."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from tqdm import tqdm

from drivee2e_data import splits, store
from drivee2e_data.cli.arguments import (
    _cell,
    _positive,
    _print_table,
    _split_options,
    _workers,
)
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.metrics import CONVENTIONS

PLANNERS = ("constant-velocity", "admlp", "camera", "tcp")
EPOCHS = {"admlp": 60, "camera": 40, "tcp": 30}
BATCH_SIZES = {"admlp": 64, "camera": 32, "tcp": 32}
LEARNING_RATES = {"admlp": 1e-3, "camera": 1e-3, "tcp": 3e-4}


def _cache_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--workers",
        type=_workers,
        default="auto",
        help="processes building the feature cache (default auto: one per core)",
    )
    parser.add_argument(
        "--no-cache",
        action="store_true",
        help="read the logs sample by sample instead of the feature cache (the reference path)",
    )


def add_cache(commands) -> None:  # type: ignore[no-untyped-def]
    """The `cache` command's arguments."""
    cache = commands.add_parser(
        "cache", help="decode what a model reads from a split once, into DATA/features/"
    )
    cache.add_argument("data", type=Path, help="data root (collected, split)")
    cache.add_argument("--model", choices=PLANNERS, required=True, help="whose features")
    _split_options(cache, "train")
    cache.add_argument(
        "--workers",
        type=_workers,
        default="auto",
        help="processes, one clip each at a time (default auto: one per core)",
    )


def add_train(commands) -> None:  # type: ignore[no-untyped-def]
    """The `train` command's arguments."""
    train = commands.add_parser("train", help="train a baseline planner on a split")
    train.add_argument("model", choices=("admlp", "camera", "tcp"), help="which baseline")
    train.add_argument("data", type=Path, help="data root (collected, split)")
    _split_options(train, "train")
    train.add_argument("--out", type=Path, required=True, help="checkpoint to write (resumes)")
    train.add_argument(
        "--epochs", type=_positive, default=None, help="default: admlp 60, camera 40, tcp 30"
    )
    train.add_argument(
        "--batch-size", type=_positive, default=None, help="default: admlp 64, others 32"
    )
    train.add_argument(
        "--learning-rate", type=float, default=None, help="default: tcp 3e-4, others 1e-3"
    )
    train.add_argument("--seed", type=int, default=0)
    train.add_argument(
        "--width",
        type=_positive,
        default=None,
        help="tcp: channels of the trunk's first stage (default 64, ResNet-18's; a smaller "
        "trunk trains and drives faster, for trying the pipeline out)",
    )
    train.add_argument(
        "--device",
        default="auto",
        help="where to train (auto: the camera models on cuda where there is one, admlp on the "
        "cpu; cuda:N picks a GPU, so several trainings run side by side)",
    )
    train.add_argument(
        "--no-cuda-graphs",
        action="store_true",
        help="tcp on a GPU: launch each step's kernels from Python instead of replaying the "
        "step as CUDA graphs (slower; to compare the two)",
    )
    _cache_options(train)


def add_predict(commands) -> None:  # type: ignore[no-untyped-def]
    """The `predict` command's arguments."""
    predict = commands.add_parser(
        "predict", help="a baseline's plans for every sample of a split (predictions file)"
    )
    predict.add_argument("data", type=Path, help="data root")
    _split_options(predict, "val")
    predict.add_argument("--model", choices=PLANNERS, required=True)
    predict.add_argument(
        "--checkpoint", type=Path, help="the model's checkpoint (admlp, camera, tcp)"
    )
    predict.add_argument("--out", type=Path, required=True, help="predictions Parquet to write")
    predict.add_argument(
        "--device",
        default="auto",
        help="where the network plans (auto: the camera models on cuda where there is one, else "
        "the cpu; cuda:N picks a GPU). A GPU's arithmetic differs from the CPU's in the last bits",
    )
    _cache_options(predict)


def add_openloop(commands) -> None:  # type: ignore[no-untyped-def]
    """The `openloop` command's arguments."""
    openloop = commands.add_parser(
        "openloop",
        help="score a predictions file, or a baseline's plans made in the same process: L2 and "
        "collision rate, per category",
    )
    openloop.add_argument("data", type=Path, help="data root")
    _split_options(openloop, "val")
    plans = openloop.add_mutually_exclusive_group(required=True)
    plans.add_argument("--predictions", type=Path, help="Parquet (docs/loaders.md)")
    plans.add_argument(
        "--model",
        choices=PLANNERS,
        help="plan the split with this baseline first (as `predict` would, in the same "
        "process: its start paid once)",
    )
    openloop.add_argument("--checkpoint", type=Path, help="with --model: its checkpoint")
    openloop.add_argument(
        "--device", default="auto", help="with --model: where its network plans (as `predict`)"
    )
    openloop.add_argument(
        "--write-predictions", type=Path, default=None, help="with --model: also save its plans"
    )
    openloop.add_argument(
        "--convention",
        nargs="+",
        choices=CONVENTIONS,
        default=["stp3"],
        help="one or more (scored in one process: the command's start paid once)",
    )
    openloop.add_argument(
        "--json",
        type=Path,
        default=None,
        help="also save each table as JSON; with several conventions the path holds "
        "{convention} (for example plans_{convention}.json)",
    )
    _cache_options(openloop)


def add_export(commands) -> None:  # type: ignore[no-untyped-def]
    """The `export` command's arguments."""
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


def _labels_only(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    """The split's samples without sensor data or map labels: what planners of the ego's
    state and the metrics read (map labels would be computed for every sample and never read)."""
    from drivee2e_data.loaders.dataset import DriveE2EDataset

    return DriveE2EDataset(args.data, args.split, args.split_name, cameras=(), with_map=False)


def feature_spec(model: str):  # type: ignore[no-untyped-def]
    """The feature spec a model's training and open-loop planning read."""
    from drivee2e_data.agents import admlp, camera, tcp

    return {"admlp": admlp.FEATURES, "constant-velocity": admlp.FEATURES,
            "camera": camera.FEATURES, "tcp": tcp.FEATURES}[model]  # fmt: skip


def _scoring_spec():  # type: ignore[no-untyped-def]
    from drivee2e_data.loaders.cache import SCORING

    return SCORING


def _features(args: argparse.Namespace, model: str):  # type: ignore[no-untyped-def]
    """The split's samples as `model` reads them: its feature cache (built where missing), or
    with `--no-cache` the Dataset over the logs."""
    spec = feature_spec(model)
    if getattr(args, "no_cache", False):
        return spec.dataset(args.data, args.split, args.split_name)
    return _cached(args, spec)


def _cached(args: argparse.Namespace, spec):  # type: ignore[no-untyped-def]
    """The split's feature cache of `spec`, built first where any clip is missing."""
    from drivee2e_data.loaders import cache

    workers = _worker_count(args.workers)
    with tqdm(unit="sample", desc=f"caching {spec.name} features", disable=None) as bar:
        report = cache.build(args.data, spec, args.split, args.split_name, workers, bar.update)
    if report.written:
        print(
            f"cached {spec.name} features of {len(report.written)} clips "
            f"({len(report.reused)} already cached): {report.folder}"
        )
    return cache.FeatureCache(args.data, spec, args.split, args.split_name)


def _worker_count(workers: int | str) -> int:
    if workers != "auto":
        return int(workers)
    from drivee2e_data.processes import usable_cores

    return usable_cores()


def run_cache(args: argparse.Namespace) -> int:
    import time

    from drivee2e_data.loaders import cache

    spec = feature_spec(args.model)
    start = time.perf_counter()
    with tqdm(unit="sample", desc=f"caching {spec.name} features", disable=None) as bar:
        report = cache.build(
            args.data, spec, args.split, args.split_name, _worker_count(args.workers), bar.update
        )
    seconds = time.perf_counter() - start
    print(
        f"{spec.name} features of split {args.split}: {report.samples} samples, "
        f"{len(report.written)} clips written, {len(report.reused)} already cached, "
        f"{seconds:.1f} s; {report.folder}"
    )
    return 0


def run_train(args: argparse.Namespace) -> int:
    import functools

    from drivee2e_data.agents import admlp, camera, tcp
    from drivee2e_data.agents.device import model_device
    from drivee2e_data.agents.training import TrainOptions

    epochs = args.epochs or EPOCHS[args.model]
    batch_size = args.batch_size or BATCH_SIZES[args.model]
    learning_rate = args.learning_rate or LEARNING_RATES[args.model]
    options = TrainOptions(epochs, batch_size, learning_rate, args.seed)
    device = model_device(args.device, args.model)
    if args.width is not None and args.model != "tcp":
        raise DriveE2EError(f"--width: only tcp's trunk has a width, not {args.model}'s")
    if args.model == "camera":
        trainer = functools.partial(camera.train, device=device)
    elif args.model == "tcp":
        trainer = functools.partial(
            tcp.train,
            device=device,
            width=args.width or tcp.RESNET18_WIDTH,
            cuda_graphs=not args.no_cuda_graphs,
        )
    else:
        trainer = functools.partial(admlp.train, device=device)
    dataset = _features(args, args.model)
    with (
        tqdm(total=len(dataset), unit="sample", desc="reading", disable=None) as reading,
        tqdm(total=epochs, unit="epoch", desc=f"training {args.model}", disable=None) as bar,
    ):
        ended: list[float] = []  # when each epoch of this call ended

        def on_epoch(epoch: int, loss: float) -> None:
            ended.append(time.perf_counter())
            bar.n = epoch
            bar.set_postfix(loss=f"{loss:.3f}")
            bar.refresh()

        began = time.perf_counter()
        saved = trainer(dataset, args.out, options, on_epoch, reading.update)
    pace = ""
    if ended:  # the epochs after the first: the first also pays the loader's and device's start
        pace = f"; {len(ended)} epochs in {ended[-1] - began:.1f} s (the first {ended[0] - began:.1f} s"
        if len(ended) > 1:
            rate = saved["samples"] * (len(ended) - 1) / (ended[-1] - ended[0])
            pace += f", then {rate:.0f} samples/s"
        pace += ")"
    print(
        f"{args.model}: {saved['samples']} samples, {saved['epoch']} epochs, final L1 loss "
        f"{saved['losses'][-1]:.3f} m; wrote {args.out}{pace}"
    )
    return 0


def _planner(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    from drivee2e_data.agents import admlp, camera, tcp
    from drivee2e_data.agents.constant_velocity import ConstantVelocity
    from drivee2e_data.agents.device import model_device

    if args.model == "constant-velocity":
        return ConstantVelocity()
    if args.checkpoint is None:
        raise DriveE2EError(
            f"--model {args.model} needs --checkpoint (drivee2e train {args.model} writes one)"
        )
    if args.model == "admlp":
        return admlp.load(args.checkpoint)
    device = model_device(args.device, args.model)
    if args.model == "tcp":
        return tcp.TCPPlanner(args.checkpoint, device)
    return camera.CameraPlanner(args.checkpoint, device)


def run_predict(args: argparse.Namespace) -> int:
    table = _plan(args)
    print(f"wrote {args.out}: {table.num_rows} plans for split {args.split}")
    return 0


def _plan(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    """`args.model`'s plans for every sample of the split, as a predictions table; written to
    `args.out` (`predict`) or `args.write_predictions` (`openloop --model`) where given."""
    from drivee2e_data import openloop

    planner = _planner(args)
    dataset = _features(args, args.model)
    with tqdm(
        total=len(dataset), unit="sample", desc=f"planning ({args.model})", disable=None
    ) as bar:
        table = openloop.predict(dataset, planner, bar.update)
    out = getattr(args, "out", None) or getattr(args, "write_predictions", None)
    if out is not None:
        openloop.write_predictions(out, table)
    return table


def run_openloop(args: argparse.Namespace) -> int:
    from drivee2e_data import openloop

    conventions = list(dict.fromkeys(args.convention))
    if args.json is not None and len(conventions) > 1 and "{convention}" not in str(args.json):
        raise DriveE2EError(
            f"--json {args.json}: {len(conventions)} conventions need one file each; put "
            "{convention} in the path (for example plans_{convention}.json)"
        )
    if args.model is None and (args.checkpoint or args.write_predictions):
        option = "--checkpoint" if args.checkpoint else "--write-predictions"
        raise DriveE2EError(f"{option} goes with --model (plans made here), not --predictions")
    table = _plan(args) if args.model is not None else None
    dataset = _labels_only(args) if args.no_cache else _cached(args, _scoring_spec())
    if table is None:
        plans = openloop.read_predictions(args.predictions, dataset)
    else:
        plans = openloop.plans_of(table, dataset, f"the plans of {args.model}")
        if args.write_predictions is not None:
            print(f"wrote {args.write_predictions}: {table.num_rows} plans")
    with tqdm(total=len(plans), unit="sample", desc="scoring", disable=None) as bar:
        scored = openloop.score(dataset, plans, conventions, bar.update)
    for convention, results in scored.items():
        _print_openloop(results, convention, args.split, len(plans), len(dataset))
        if args.json is not None:
            path = Path(str(args.json).replace("{convention}", convention))
            document = {"convention": convention, "split": args.split, "results": results}
            path.parent.mkdir(parents=True, exist_ok=True)
            store.write_bytes_atomic(path, json.dumps(document, indent=2).encode())
            print(f"wrote {path}")
    return 0


def _print_openloop(
    results: dict[str, dict[str, float]], convention: str, split: str, planned: int, samples: int
) -> None:
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
        f"open-loop, {convention} convention, split {split}: {planned} of {samples} samples planned"
    )
    _print_table(header, rows)


def run_export(args: argparse.Namespace) -> int:
    from drivee2e_data.export.infos import export_infos
    from drivee2e_data.export.nuscenes import export_nuscenes

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
