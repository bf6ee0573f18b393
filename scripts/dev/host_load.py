"""Whether a run is bound by the host's CPUs or by its GPUs: the CPUs' user, system and idle
shares (`/proc/stat`, every second) and each GPU's utilisation (`nvidia-smi`, twice a second,
where there is one) while a command runs.

    python scripts/dev/host_load.py [--interval 1.0] -- drivee2e collect DATA --workers auto

Prints the shares over the run's busy middle (the seconds whose CPUs were at least half as busy
as the run's busiest second: the workers' start and the run's end left out) and over the whole
run, and the command's exit status (its own). A collection whose CPUs stay near 100% user with
GPUs well short of it is bound by the CPUs; one whose GPU is near 100% by the GPU, whatever the
CPUs show (the driver spins while a read waits, docs/benchmarks.md, twenty-second session).
Linux only.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from bench_gpus import _gpu_load

# /proc/stat's first line: cpu user nice system idle iowait irq softirq steal (jiffies)
FIELDS = ("user", "nice", "system", "idle", "iowait", "irq", "softirq", "steal")


@dataclass(frozen=True)
class CpuShares:
    """Shares (0-1) of the CPUs' time between two readings of /proc/stat."""

    user: float  # user and nice
    system: float  # system, irq and softirq
    idle: float  # idle and iowait
    steal: float

    @property
    def busy(self) -> float:
        return self.user + self.system


def cpu_times(stat_text: str) -> dict[str, int]:
    """The all-CPU line of /proc/stat's text as jiffies by field (`FIELDS`)."""
    for line in stat_text.splitlines():
        parts = line.split()
        if parts and parts[0] == "cpu":
            return dict(zip(FIELDS, (int(v) for v in parts[1 : 1 + len(FIELDS)]), strict=False))
    raise ValueError("/proc/stat: no 'cpu' line")


def shares(before: dict[str, int], after: dict[str, int]) -> CpuShares:
    """What the CPUs did between two `cpu_times` readings (all zero if no time passed)."""
    spent = {name: after.get(name, 0) - before.get(name, 0) for name in FIELDS}
    total = sum(spent.values())
    if total <= 0:
        return CpuShares(0.0, 0.0, 0.0, 0.0)
    return CpuShares(
        (spent["user"] + spent["nice"]) / total,
        (spent["system"] + spent["irq"] + spent["softirq"]) / total,
        (spent["idle"] + spent["iowait"]) / total,
        spent["steal"] / total,
    )


def busy_middle(seconds: list[CpuShares]) -> list[CpuShares]:
    """The seconds at least half as busy as the busiest one (the run without its start and
    end)."""
    if not seconds:
        return []
    peak = max(s.busy for s in seconds)
    return [s for s in seconds if s.busy >= peak / 2]


def mean(seconds: list[CpuShares]) -> CpuShares:
    if not seconds:
        return CpuShares(0.0, 0.0, 0.0, 0.0)
    count = len(seconds)
    return CpuShares(*(sum(getattr(s, f) for s in seconds) / count
                       for f in ("user", "system", "idle", "steal")))  # fmt: skip


def describe(label: str, share: CpuShares) -> str:
    return (
        f"{label}: user {100 * share.user:.1f}%, system {100 * share.system:.1f}%, "
        f"idle {100 * share.idle:.1f}%, steal {100 * share.steal:.1f}%"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--interval", type=float, default=1.0, help="seconds between readings")
    parser.add_argument("command", nargs=argparse.REMAINDER, help="the command, after --")
    args = parser.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("no command given (put it after --)")
    stat = Path("/proc/stat")
    if not stat.exists():
        parser.error("/proc/stat not found: Linux only")
    with tempfile.TemporaryDirectory() as folder:
        samples = Path(folder) / "gpus.csv"
        sampler = None
        if shutil.which("nvidia-smi"):
            with open(samples, "w") as out:
                sampler = subprocess.Popen(
                    ["nvidia-smi", "--query-gpu=index,utilization.gpu", "--format=csv,noheader",
                     "-lms", "500"],
                    stdout=out, stderr=subprocess.DEVNULL,
                )  # fmt: skip
        start = time.perf_counter()
        process = subprocess.Popen(command)
        readings = [cpu_times(stat.read_text())]
        seconds: list[CpuShares] = []
        while process.poll() is None:
            time.sleep(args.interval)
            readings.append(cpu_times(stat.read_text()))
            seconds.append(shares(readings[-2], readings[-1]))
        wall = time.perf_counter() - start
        if sampler is not None:
            sampler.terminate()
            sampler.wait()
        load = _gpu_load(samples) if sampler is not None else "no nvidia-smi"
    print(f"\n{' '.join(command)}: exit {process.returncode}, {wall:.1f} s")
    print(describe("CPUs, busy middle", mean(busy_middle(seconds))))
    print(describe("CPUs, whole run", shares(readings[0], readings[-1])))
    print(f"GPUs: {load}")
    return process.returncode


if __name__ == "__main__":
    sys.exit(main())
