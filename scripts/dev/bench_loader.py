"""Loader throughput: `DriveE2EDataset` reading the MCAP logs against the same Dataset reading
the same JPEGs from a nuScenes-style folder of files (the reference), in one run.

    python scripts/dev/bench_loader.py DATA [--samples 400] [--workers 2] [--batch-size 4]
                                        [--device cuda]

DATA is a collected data root with a split manifest (`drivee2e split DATA`). The reference
folder is written first by `export_nuscenes(keyframe_every=1)` (every frame's six JPEGs as
files, as nuScenes keeps `samples/CAM_*/*.jpg`); its Dataset differs from ours only in where
the JPEG bytes come from, so the ratio isolates storage. Each configuration iterates a
DataLoader (persistent workers, warmed up on one pass of 2 batches per worker) over the same
samples; samples/s is the median of `--passes` timed passes, alternating between the two loaders. Peak memory per worker is VmHWM of the
worker processes. With `--device cuda`, the `decode="none"` path decodes each batch with
nvJPEG in the main process.
"""

from __future__ import annotations

import argparse
import gc
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch
from torch.utils.data import DataLoader, Subset

from drivee2e_data.export import common
from drivee2e_data.export.nuscenes import export_nuscenes
from drivee2e_data.loaders import DriveE2EDataset, collate, decode_jpegs
from drivee2e_data.logs.reader import LogReader


class FolderDataset(DriveE2EDataset):
    """The reference: the same samples, JPEGs read from files of a nuScenes export."""

    def __init__(self, folder: Path, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        super().__init__(*args, **kwargs)
        self.folder = folder

    def jpegs(self, log: LogReader, scenario_id: str, frame: int) -> list[bytes]:
        t_ns = int(log.time_of(frame))
        return [
            (self.folder / common.sample_file(scenario_id, camera, t_ns, "jpg")).read_bytes()
            for camera in self.cameras
        ]


def _worker_peak_bytes() -> int:
    """Largest VmHWM among this process's children (the DataLoader's workers)."""
    me, peak = os.getpid(), 0
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            status = Path(f"/proc/{entry}/status").read_text()
        except OSError:
            continue
        fields = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
        if int(fields.get("PPid", "0").strip() or 0) == me and "VmHWM" in fields:
            peak = max(peak, int(fields["VmHWM"].split()[0]) * 1024)
    return peak


def measure(*args, **kwargs):  # type: ignore[no-untyped-def]
    """`_measure`, then the loaders' workers are gone before the next configuration starts."""
    result = _measure(*args, **kwargs)
    gc.collect()
    return result


def _measure(
    datasets: list[DriveE2EDataset],
    indices: list[int],
    args: argparse.Namespace,
    device: str | None,
) -> tuple[list[float], int]:
    """Samples/s of each dataset over `indices` (passes alternate between the datasets, so a
    slow spell of the machine hits both alike), and the peak bytes of any worker."""
    loaders = [
        DataLoader(
            Subset(dataset, indices),
            batch_size=args.batch_size,
            num_workers=args.workers,
            persistent_workers=args.workers > 0,
            collate_fn=collate,
            prefetch_factor=4 if args.workers else None,
        )
        for dataset in datasets
    ]
    first = datasets[0].log_info[datasets[0].samples[0][0]]["cameras"][datasets[0].cameras[0]]

    def one_pass(loader: DataLoader, limit: int | None = None) -> int:
        count = 0
        for k, batch in enumerate(loader):
            if device is not None:
                batch = decode_jpegs(batch, first["full_size"], datasets[0].image_size, device)
                torch.cuda.synchronize()
            count += len(batch["scene_token"])
            if limit is not None and k + 1 >= limit:
                break
        return count

    for loader in loaders:
        one_pass(loader, limit=2 * max(1, args.workers))  # start the workers, open the logs
    rates: list[list[float]] = [[] for _ in loaders]
    for _ in range(args.passes):
        for k, loader in enumerate(loaders):
            start = time.perf_counter()
            count = one_pass(loader)
            rates[k].append(count / (time.perf_counter() - start))
    return [statistics.median(r) for r in rates], _worker_peak_bytes()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--split", default="all")
    parser.add_argument("--samples", type=int, default=400)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--batch-size", type=int, default=4)
    parser.add_argument("--passes", type=int, default=3, help="timed passes (the median counts)")
    parser.add_argument("--device", default=None, help="cuda: also measure decode on the GPU")
    parser.add_argument(
        "--folder", type=Path, default=None, help="the reference export (written if absent)"
    )
    args = parser.parse_args()

    folder = args.folder or Path(tempfile.mkdtemp(prefix="bench_loader_")) / "nuscenes"
    if not folder.exists():
        start = time.perf_counter()
        export_nuscenes(args.data, folder, split=args.split, keyframe_every=1)
        print(f"reference folder: {folder} ({time.perf_counter() - start:.0f} s to write)")
    probe = DriveE2EDataset(args.data, args.split)
    step = max(1, len(probe) // args.samples)
    indices = list(range(0, len(probe), step))[: args.samples]
    width, height = probe.log_info[probe.samples[0][0]]["cameras"]["CAM_FRONT"]["full_size"]
    half = (width // 2, height // 2)
    print(
        f"{len(indices)} samples of {len(probe)} ({args.split}), six cameras {width}x{height}, "
        f"{args.workers} workers, batch {args.batch_size}, torch threads {torch.get_num_threads()}"
    )
    rows = []
    modes = [("cpu", None, "decoded on the CPU")]
    if args.device is not None:
        modes.append(("none", args.device, f"decoded on {args.device}"))
    for decode, device, where in modes:
        for label, size in (("full", None), ("half", half)):
            options = {"image_size": size, "decode": decode}
            (reference, ours), peak = measure(
                [
                    FolderDataset(folder, args.data, args.split, **options),
                    DriveE2EDataset(args.data, args.split, **options),
                ],
                indices,
                args,
                device,
            )
            rows.append((f"{label} size, {where}", reference, ours, peak))
    print(
        f"{'configuration':38s} {'files (ref)':>12s} {'MCAP logs':>10s} {'ratio':>6s} {'peak/worker':>12s}"
    )
    for label, reference, ours, peak in rows:
        print(
            f"{label:38s} {reference:10.1f}/s {ours:8.1f}/s {ours / reference:6.2f} {peak / 2**30:9.2f} GiB"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
