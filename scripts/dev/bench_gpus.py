"""Several GPUs against one on the same host: `drivee2e collect --workers auto` on the real mix
with every GPU and every core, against one GPU with its share of the cores, the runs
alternating.

    python scripts/dev/bench_gpus.py [--clips 16] [--seed 0] [--max-frames 0] [--repeats 2]
        [--data DIR] [-- EXTRA COLLECT ARGS]

The one-GPU run is `--gpus D` (the first GPU device) with the command held to the first
CPUs / GPUs of the host's CPUs (CPU affinity, which the host plan reads: `--workers auto` then
starts that many workers): the host cut to what a one-GPU host of its kind has. The other run
is the command as a user runs it (`--gpus` left to its default, every GPU). The clips are
`drivee2e synth --clips N --seed S`, curated, or a copy of `--data`'s; each run collects them
afresh through the command line. Prints each run's frames/s (the command's summary line) and
the GPUs' load (`nvidia-smi`, where it is), the mean per configuration, their ratio, and
whether every log is the same bytes in both (MD5). Needs two GPU devices or more (an NVIDIA
host with NVIDIA's EGL vendor file, docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

from bench_collect import copy_scenarios
from bench_versions import RATE, cli

from drivee2e_data.sim.egl_devices import gpu_devices


def _digests(logs: Path) -> dict[str, str]:
    return {path.name: hashlib.md5(path.read_bytes()).hexdigest() for path in logs.glob("*.mcap")}


def _gpu_load(samples: Path) -> str:
    """Mean utilisation per GPU from `nvidia-smi --query-gpu=index,utilization.gpu` rows."""
    busy: dict[str, list[float]] = collections.defaultdict(list)
    for line in samples.read_text().splitlines():
        fields = [field.strip() for field in line.split(",")]
        if len(fields) == 2 and fields[1].split()[0].isdigit():
            busy[fields[0]].append(float(fields[1].split()[0]))
    return ", ".join(f"{gpu}: {sum(v) / len(v):.0f}%" for gpu, v in busy.items()) or "not sampled"


def run(collect: list[str], data: Path, cpus: set[int], folder: Path) -> tuple[int, float, str]:
    """One collection with the CPU affinity `cpus` (inherited by the command); returns frames,
    frames/s and the GPUs' load."""
    shutil.rmtree(data / "logs", ignore_errors=True)
    samples = folder / "nvidia-smi.csv"
    sampler = None
    if shutil.which("nvidia-smi"):
        with open(samples, "w") as stream:
            sampler = subprocess.Popen(
                ["nvidia-smi", "--query-gpu=index,utilization.gpu", "--format=csv,noheader",
                 "-l", "1"], stdout=stream, stderr=subprocess.DEVNULL,
            )  # fmt: skip
    everything = os.sched_getaffinity(0)
    os.sched_setaffinity(0, cpus)
    try:
        output = cli(collect, None)
    finally:
        os.sched_setaffinity(0, everything)
        if sampler is not None:
            sampler.terminate()
            sampler.wait()
    match = RATE.search(output)
    if match is None:
        raise SystemExit(f"no rate in the collector's output:\n{output}")
    load = _gpu_load(samples) if sampler is not None else "not sampled"
    return int(match.group(1)), float(match.group(3)), load


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clips", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-frames", type=int, default=0, help="0: whole clips")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--data", type=Path, default=None, help="copy these clips, not synth")
    parser.add_argument("extra", nargs="*", help="more `drivee2e collect` arguments (after --)")
    args = parser.parse_args()
    gpus = gpu_devices()
    if len(gpus) < 2:
        raise SystemExit(f"needs two GPU devices or more; EGL shows {len(gpus)} here")
    cpus = sorted(os.sched_getaffinity(0))
    share = set(cpus[: max(1, len(cpus) // len(gpus))])
    print(f"host: {len(cpus)} CPUs, GPU devices {', '.join(map(str, gpus))}; one GPU gets "
          f"{len(share)} CPUs")  # fmt: skip
    folder = Path(tempfile.mkdtemp(prefix="bench_gpus_"))
    try:
        data = folder / "data"
        if args.data is not None:
            copy_scenarios(args.data, data)
        else:
            synth = ["synth", "--out", str(data), "--clips", str(args.clips)]
            cli([*synth, "--seed", str(args.seed)], None)
            cli(["curate", str(data)], None)
        collect = ["collect", str(data), "--workers", "auto", *args.extra]
        if args.max_frames:
            collect += ["--max-frames", str(args.max_frames)]
        runs = {
            f"one GPU ({gpus[0]}), {len(share)} CPUs": ([*collect, "--gpus", str(gpus[0])], share),
            f"{len(gpus)} GPUs, {len(cpus)} CPUs": (collect, set(cpus)),
        }
        rates: dict[str, list[float]] = {name: [] for name in runs}
        digests: dict[str, dict[str, str]] = {}
        for repeat in range(args.repeats):
            for name, (command, allowed) in runs.items():
                start = time.perf_counter()
                frames, rate, load = run(command, data, allowed, folder)
                wall = time.perf_counter() - start
                rates[name].append(rate)
                digests[name] = _digests(data / "logs")
                print(f"run {repeat + 1} {name:24s} {frames} frames  {rate:7.2f} frames/s  "
                      f"(whole command {wall:.1f} s)  GPU busy {load}", flush=True)  # fmt: skip
        means = {name: sum(values) / len(values) for name, values in rates.items()}
        one, every = means.values()
        print("; ".join(f"{name}: {rate:.2f} frames/s" for name, rate in means.items())
              + f"; ratio {every / one:.3f}")  # fmt: skip
        first, second = digests.values()
        same = sum(first.get(log) == digest for log, digest in second.items())
        print(f"logs: the same bytes with one GPU and with {len(gpus)}: {same} of {len(second)}")
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
