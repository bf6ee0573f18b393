"""What suits the host the collector runs on: how many worker processes, and which LiDAR.

Each worker renders on one core (llvmpipe, or the CPU side of a GPU renderer) and peaks under
1 GiB (docs/benchmarks.md), so the workers are the usable cores, no more than the units of work
the frames make (`collect.segments`: a clip is cut into segments, so a few long clips still
keep every core busy) and no more than the memory allows at `WORKER_MEMORY_GIB` each. On a host
with several GPUs the workers' GL contexts are spread over them round robin (`gpus`). Where an
OpenGL renderer works (the GL renderer or pybullet's EGL plugin, on a GPU or on Mesa's
llvmpipe), the LiDAR is read from depth images (several times faster a sweep than ray casting,
docs/benchmarks.md); with TinyRenderer, ray casting.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path

from drivee2e_data.collect.segments import shortest_unit
from drivee2e_data.processes import usable_cores
from drivee2e_data.sim import mesa
from drivee2e_data.sim.world import resolve_renderer

RENDERER_NAMES = {"gl": "GL renderer", "egl": "pybullet EGL", "tiny": "TinyRenderer"}
WORKER_MEMORY_GIB = 1.5  # a worker's peak (0.7-0.8 GiB measured) with room to spare


@dataclass(frozen=True)
class HostPlan:
    workers: int
    lidar: str  # "raycast" or "depth"
    cores: int
    memory_gib: float
    gpu: bool
    renderer: str  # "gl", "egl" or "tiny": what "auto" resolved to here
    gpus: int = 0  # EGL GPU devices the GL renderer's workers share round robin
    mesa: str = ""  # which Mesa draws, where the GL renderer draws on a CPU (`sim.mesa`)
    workers_given: bool = False  # the user gave the workers (`given`); the host chose the rest

    def given(self, workers: int) -> HostPlan:
        """The plan with the user's number of workers in place of the host's."""
        return dataclasses.replace(self, workers=workers, workers_given=True)

    def describe(self) -> str:
        device = "an NVIDIA GPU" if self.gpu else "no GPU"
        if self.gpus > 1:
            device = f"{self.gpus} GPUs"
        renderer = RENDERER_NAMES[self.renderer] + (f" on {self.mesa}" if self.mesa else "")
        return (
            f"host: {self.cores} cores, {self.memory_gib:.0f} GiB, {device}, {renderer} -> "
            f"{self.workers} worker{'s' if self.workers != 1 else ''} "
            f"(--workers {self.workers if self.workers_given else 'auto'}), "
            f"{self.lidar} LiDAR"
        )


def memory_gib() -> float:
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30


def nvidia_gpu() -> bool:
    """Whether the NVIDIA driver is loaded (its proc entry or a device node exists)."""
    return Path("/proc/driver/nvidia/version").exists() or Path("/dev/nvidia0").exists()


def plan(
    frames: int,
    cores: int | None = None,
    memory: float | None = None,
    gpu: bool | None = None,
    renderer: str = "auto",
    gpus: int = 0,
    sensor_every: int = 1,
) -> HostPlan:
    """Workers and LiDAR for collecting `frames` frames (over all clips, sensors at every
    `sensor_every`-th) here with `renderer` (the measurements may be given; "auto" is resolved
    by trying the renderers, `sim.world.resolve_renderer`), no more workers than units
    (`segments.shortest_unit`). Every worker does its own CPU work (LiDAR, boxes, JPEG), so the
    GPUs (`gpus`, those the workers share) do not add workers. Camera images are finished on the
    CPU wherever: on an H100 host, 16 workers finishing theirs on the GPU (`--post-process
    cuda`) collected 0.65x as fast (docs/benchmarks.md)."""
    cores = usable_cores() if cores is None else cores
    memory = memory_gib() if memory is None else memory
    gpu = nvidia_gpu() if gpu is None else gpu
    renderer = resolve_renderer(renderer)
    units = max(1, frames // shortest_unit(sensor_every))
    workers = max(1, min(cores, units, int(memory // WORKER_MEMORY_GIB)))
    lidar = "raycast" if renderer == "tiny" else "depth"
    drawn_by = mesa.describe() if renderer in ("gl", "egl") and not gpu else ""
    return HostPlan(workers, lidar, cores, memory, gpu, renderer, gpus if renderer == "gl" else 0,
                    drawn_by)  # fmt: skip
