"""What suits the host the collector runs on: how many worker processes, and which LiDAR.

Each worker renders on one core (llvmpipe, or the CPU side of a GPU renderer) and peaks under
1 GiB (docs/benchmarks.md), so the workers are the usable cores, no more than the clips and no
more than the memory allows at `WORKER_MEMORY_GIB` each. Where an NVIDIA GPU is present, the
LiDAR is read from depth images (3.45x faster a sweep there); on a CPU renderer ray casting is
as fast and stays the default.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

WORKER_MEMORY_GIB = 1.5  # a worker's peak (0.7-0.8 GiB measured) with room to spare


@dataclass(frozen=True)
class HostPlan:
    workers: int
    lidar: str  # "raycast" or "depth"
    cores: int
    memory_gib: float
    gpu: bool

    def describe(self) -> str:
        device = "an NVIDIA GPU" if self.gpu else "no GPU"
        return (
            f"host: {self.cores} cores, {self.memory_gib:.0f} GiB, {device} -> "
            f"{self.workers} worker{'s' if self.workers != 1 else ''} (--workers auto), "
            f"{self.lidar} LiDAR"
        )


def usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def memory_gib() -> float:
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30


def nvidia_gpu() -> bool:
    """Whether the NVIDIA driver is loaded (its proc entry or a device node exists)."""
    return Path("/proc/driver/nvidia/version").exists() or Path("/dev/nvidia0").exists()


def plan(
    clips: int,
    cores: int | None = None,
    memory: float | None = None,
    gpu: bool | None = None,
) -> HostPlan:
    """Workers and LiDAR for collecting `clips` clips here (the measurements may be given)."""
    cores = usable_cores() if cores is None else cores
    memory = memory_gib() if memory is None else memory
    gpu = nvidia_gpu() if gpu is None else gpu
    workers = max(1, min(cores, max(clips, 1), int(memory // WORKER_MEMORY_GIB)))
    return HostPlan(workers, "depth" if gpu else "raycast", cores, memory, gpu)
