"""`drivee2e collect` through the CLI with the system's Mesa (the reference) and the Mesa that
`drivee2e mesa --fetch` put in place, runs alternating, on a machine that draws with llvmpipe.

    python scripts/dev/bench_mesa.py [--data DIR | --clips 16 --seed 0] [--max-frames 30]
        [--repeats 2] [--render FRAMES] [-- EXTRA COLLECT ARGS]

The clips are `drivee2e synth --clips N --seed S` curated once (or the curated data root
`--data`, whose logs folder is replaced); each run collects all of them into a fresh logs
folder with `--workers auto`. The reference runs with `DRIVEE2E_MESA=system`, the other with the
fetched Mesa (`drivee2e mesa` says which). Prints each run's frames/s (the CLI's summary line),
the mean per Mesa and the ratio, whether each Mesa's runs wrote the same log bytes (MD5), and
how many logs differ between the two (they may: a pixel where a triangle's edge meets a pixel
centre). `--render N` also times the six cameras of every clip over N frames with each.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import tempfile
from pathlib import Path

from bench_versions import RATE, cli, render_times

from drivee2e_data.sim import mesa

REFERENCE, FETCHED = "system Mesa", "fetched Mesa"


def log_digests(logs: Path) -> dict[str, str]:
    return {p.name: hashlib.md5(p.read_bytes()).hexdigest() for p in sorted(logs.glob("*.mcap"))}


def choose(name: str, folder: Path) -> None:
    """The Mesa the next runs use: the reference (the system's) or the fetched one."""
    os.environ[mesa.MESA_VARIABLE] = "system" if name == REFERENCE else str(folder)
    for variable in mesa.VENDOR_VARIABLES:
        os.environ.pop(variable, None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=None, help="a curated data root")
    parser.add_argument("--clips", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-frames", type=int, default=30, help="0: whole clips")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--render", type=int, default=0, metavar="FRAMES",
                        help="also time drawing the six cameras over this many frames a clip")  # fmt: skip
    parser.add_argument("extra", nargs="*", help="more `drivee2e collect` arguments (after --)")
    args = parser.parse_args()
    folder = mesa.chosen_folder()
    fetched = None if folder is None else mesa.read_private(folder)
    if fetched is None or mesa.why_not(folder) is not None:
        raise SystemExit(f"no fetched Mesa to compare: {mesa.describe()}")
    print(f"reference: the system's Mesa; against Mesa {fetched.version} from {folder}")
    scratch = Path(tempfile.mkdtemp(prefix="bench_mesa_"))
    try:
        data = args.data
        if data is None:
            data = scratch / "data"
            cli(["synth", "--out", str(data), "--clips", str(args.clips), "--seed",
                 str(args.seed)], None)  # fmt: skip
            cli(["curate", str(data)], None)
        collect = ["collect", str(data), "--workers", "auto", *args.extra]
        if args.max_frames:
            collect += ["--max-frames", str(args.max_frames)]
        rates: dict[str, list[float]] = {REFERENCE: [], FETCHED: []}
        digests: dict[str, list[dict[str, str]]] = {REFERENCE: [], FETCHED: []}
        for repeat in range(args.repeats):
            for name in (REFERENCE, FETCHED):
                choose(name, folder)
                shutil.rmtree(data / "logs", ignore_errors=True)
                output = cli(collect, None)
                match = RATE.search(output)
                if match is None:
                    raise SystemExit(f"no rate in the collector's output:\n{output}")
                rates[name].append(float(match.group(3)))
                digests[name].append(log_digests(data / "logs"))
                print(f"run {repeat + 1} {name}: {match.group(1)} frames, "
                      f"{rates[name][-1]:.2f} frames/s", flush=True)  # fmt: skip
        means = {name: sum(values) / len(values) for name, values in rates.items()}
        print(f"{REFERENCE}: {means[REFERENCE]:.2f} frames/s; {FETCHED} {fetched.version}: "
              f"{means[FETCHED]:.2f} frames/s; ratio {means[FETCHED] / means[REFERENCE]:.3f}")  # fmt: skip
        for name, runs in digests.items():
            same = all(run == runs[0] for run in runs)
            print(f"{name}: every run's {len(runs[0])} logs the same bytes: {same}")
        first, other = digests[REFERENCE][0], digests[FETCHED][0]
        differ = sum(first[log] != other.get(log) for log in first)
        print(f"logs whose bytes differ between the two: {differ} of {len(first)}")
        if args.render:
            times = {}
            for name in (REFERENCE, FETCHED):
                choose(name, folder)
                times[name] = render_times(data, None, args.render)
            print(
                "clip            conditions               six cameras (ms): system  fetched  ratio"
            )
            for clip, (conditions, before) in times[REFERENCE].items():
                after = times[FETCHED][clip][1]
                print(f"{clip}  {conditions:24s} {before:8.1f} {after:8.1f} {after / before:6.2f}")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    main()
