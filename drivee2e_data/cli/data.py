"""Preparing clips: `synth`, `import`, `curate` (and its occlusion variants), `scenarios`, `split`."""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

from tqdm import tqdm

from drivee2e_data import figures, pipeline, splits, store
from drivee2e_data.cli.arguments import (
    _add_cut_arguments,
    _positive,
    _positive_float,
    _print_table,
    _workers,
)
from drivee2e_data.curation.occlusion import Variant
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.evaluate import variants
from drivee2e_data.processes import usable_cores
from drivee2e_data.scenario import AgentClass

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


def add_synth(commands) -> None:  # type: ignore[no-untyped-def]
    """The `synth` command's arguments."""
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
        "--only",
        nargs="+",
        metavar="ID",
        default=None,
        help="these clips of the --clips set only (the same files as in the whole set)",
    )
    synth.add_argument(
        "--recording-seconds",
        type=_positive_float,
        default=None,
        help="instead of staged clips: one intersection's traffic this long, no staged ego, "
        "cut into clips as an import would cut it (see --cut)",
    )
    _add_cut_arguments(synth)


def add_import(commands) -> None:  # type: ignore[no-untyped-def]
    """The `import` command's arguments."""
    importer = commands.add_parser("import", help="import real traffic and maps")
    importer.add_argument("kind", choices=pipeline.IMPORT_KINDS, help="source format")
    importer.add_argument("source", type=Path, help="file or folder to import")
    importer.add_argument("--out", type=Path, required=True, help="data root to write into")
    importer.add_argument(
        "--keep-egoless", action="store_true",
        help="also write clips with no motor vehicle (no ego can be chosen; nothing collects them)",
    )  # fmt: skip
    _add_cut_arguments(importer)


def add_curate(commands) -> None:  # type: ignore[no-untyped-def]
    """The `curate` command's arguments."""
    curate = commands.add_parser("curate", help="score tracks, choose egos, label behaviours")
    curate.add_argument("data", type=Path, help="data root")
    curate.add_argument(
        "--occlusion",
        choices=("vehicle", "all"),
        default=None,
        help="instead: write the occlusion variant (agents never seen by the ego's cameras in "
        "the collected logs removed: vehicles only, or every class) to DATA/variants/",
    )
    curate.add_argument(
        "--workers",
        type=_workers,
        default="auto",
        help="processes for the expert-replay check (default auto: one per core)",
    )
    curate.add_argument(
        "--check-only",
        action="store_true",
        help="only the expert-replay check of clips not checked yet (a rerun after a stop)",
    )


def add_scenarios(commands) -> None:  # type: ignore[no-untyped-def]
    """The `scenarios` command's arguments."""
    scenarios = commands.add_parser(
        "scenarios", help="list and validate the scenarios of a data root"
    )
    scenarios.add_argument("data", type=Path, help="data root")
    scenarios.add_argument("--stats", action="store_true", help="print the dataset's distributions")
    scenarios.add_argument(
        "--plot", type=Path, default=None, help="draw the distributions to this PNG"
    )


def add_split(commands) -> None:  # type: ignore[no-untyped-def]
    """The `split` command's arguments."""
    split = commands.add_parser(
        "split", help="2:1:1 train/val/test over whole clips, stratified by behaviour"
    )
    split.add_argument("data", type=Path, help="data root")
    split.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    split.add_argument(
        "--name", default="default", help="manifest name: DATA/splits/NAME.csv (default: default)"
    )
    split.add_argument(
        "--keep-flagged",
        action="store_true",
        help="keep clips the expert-replay check of `drivee2e curate` flagged (left out by "
        "default: their expert breaks a rule)",
    )


def run_synth(args: argparse.Namespace) -> int:
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
    total = args.clips if args.only is None else len(set(args.only))
    with tqdm(total=total, unit="clip", desc="synthesising", disable=None) as bar:
        report = pipeline.synthesize(
            args.out,
            args.clips,
            args.seed,
            args.intersections,
            on_clip=lambda scenario_id, skipped: bar.update(1),
            workers=args.workers,
            only=args.only,
        )
    print(
        f"{len(report.written)} clips written, {len(report.skipped)} already present, "
        f"{len(report.maps)} maps, under {args.out}"
    )
    return 0


def run_import(args: argparse.Namespace) -> int:
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
    from drivee2e_data.sim.scenery import scenery_report

    for map_id in summary.maps:  # what each twin stands beside its roads
        print(f"scenery of {scenery_report(store.read_map(Path(args.out), map_id)).line()}")
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


def run_curate(args: argparse.Namespace) -> int:
    if not (args.data / "scenarios").is_dir():
        raise DriveE2EError(f"{args.data}: no scenarios/ folder; is this a drivee2e data root?")
    if args.occlusion is not None:
        return _occlusion(args)
    if args.check_only:
        return _check_experts(args)
    with tqdm(unit="clip", desc="curating", disable=None) as bar:
        rows = pipeline.curate(args.data, on_scenario=lambda _: bar.update(1))
    _print_curation(rows)
    return _check_experts(args)


def _check_experts(args: argparse.Namespace) -> int:
    """The expert-replay check of the curated clips, one line per flagged clip."""
    workers = usable_cores() if args.workers == "auto" else args.workers
    total = sum(
        store.read_meta(args.data, i).get("ego_id") is not None
        for i in store.scenario_ids(args.data)
    )
    with tqdm(total=total, unit="clip", desc="expert replay", disable=None) as bar:

        def done(scenario_id: str, flags: tuple) -> None:
            bar.update(1)
            if flags:
                bar.write(f"{scenario_id}: {flags[0].line()}" + _more(len(flags) - 1))

        checked = pipeline.check_experts(args.data, workers, done)
        bar.update(total - bar.n)
    flagged = {i: f for i, f in checked.items() if f}
    rules = Counter(f[0].rule for f in flagged.values())
    why = ", ".join(f"{n} {rule}" for rule, n in rules.most_common())
    left_out = f" ({why}): left out of splits unless drivee2e split --keep-flagged"
    print(
        f"expert replay: {len(checked) - len(flagged)} of {len(checked)} clips driven cleanly, "
        f"{len(flagged)} flagged{left_out if flagged else ''}"
    )
    return 0


def _more(count: int) -> str:
    return f" (and {count} more)" if count else ""


def _print_curation(rows: list) -> None:  # type: ignore[type-arg]
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


def run_scenarios(args: argparse.Namespace) -> int:
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


def run_split(args: argparse.Namespace) -> int:
    path, rows, left_out = splits.split_root(args.data, args.name, args.seed, args.keep_flagged)
    table = splits.counts_table(rows)
    _print_table(table[0], table[1:])
    print(f"wrote {path}: {len(rows)} clips")
    if left_out:
        reasons = Counter(left_out.values())
        why = "; ".join(f"{n} {reason}" for reason, n in reasons.most_common())
        print(f"{len(left_out)} clips left out ({why}); --keep-flagged keeps them")
    return 0
