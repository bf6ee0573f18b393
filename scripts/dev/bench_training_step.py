"""What bounds an image model's training: the feature cache's DataLoader alone, the training
step alone on a batch already on the device (at several batch sizes), and the step with the
ResNet trunk compiled, each in samples/s against the eager step at the training's batch size
(the reference), in one process.

    python scripts/dev/bench_training_step.py DATA --split-name MANIFEST [--model tcp]
        [--device cuda:0] [--batch-sizes 32 64 128] [--compile default reduce-overhead]

DATA holds the model's feature cache of the train split (`drivee2e cache DATA --model tcp
--split train --split-name MANIFEST`). The step is `training.fit`'s: forward (bfloat16 autocast
on a GPU), the model's loss, backward, AdamW; the compiled variants compile only the trunk (the
augmentation reads a counter on the host, which a whole-model graph cannot).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from drivee2e_data.agents import camera, tcp, training
from drivee2e_data.loaders.cache import cached


def loader_rate(source: training.Rows, batch_size: int, batches: int, cuda: bool) -> float:
    """Samples/s the DataLoader of `training.fit` delivers, after a warm-up of 20 batches (or
    half of a smaller set's)."""
    order = training._EpochOrder()
    order.batches = list(torch.split(torch.randperm(len(source)), batch_size))[: batches + 20]
    warm_up = min(20, len(order.batches) // 2)
    workers = training.loader_workers(source)
    loader = torch.utils.data.DataLoader(
        training._Batches(source), sampler=order, batch_size=None, num_workers=workers,
        pin_memory=cuda, prefetch_factor=4 if workers else None,
    )  # fmt: skip
    count, started = 0, time.perf_counter()
    for k, rows in enumerate(loader):
        if k == warm_up:
            count, started = 0, time.perf_counter()
        count += len(rows["y"])
    return count / (time.perf_counter() - started)


def step_rate(model, predict, rows, device: str, steps: int = 60) -> float:  # type: ignore[no-untyped-def]
    """Samples/s of training steps on `rows` (on `device`), after 20 steps of warm-up."""
    cuda = torch.device(device).type == "cuda"
    optimiser = torch.optim.AdamW(model.parameters(), lr=3e-4, fused=cuda or None)
    autocast = torch.autocast("cuda", torch.bfloat16, enabled=cuda)
    model.train()
    for k in range(steps + 20):
        if k == 20:
            if cuda:
                torch.cuda.synchronize()
            started = time.perf_counter()
        with autocast:
            predicted, extra = predict(model, rows)
        mask = rows["mask"].float()[..., None]
        loss = ((predicted.float() - rows["y"]).abs() * mask).sum() / mask.sum() / 2
        optimiser.zero_grad()
        (loss + extra.float()).backward()
        optimiser.step()
    if cuda:
        torch.cuda.synchronize()
    return steps * len(rows["y"]) / (time.perf_counter() - started)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--split-name", default="default")
    parser.add_argument("--model", choices=["tcp", "camera"], default="tcp")
    parser.add_argument("--device", default="cuda:0" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--batch-sizes", type=int, nargs="+", default=[32, 64, 128])
    parser.add_argument("--compile", nargs="*", default=[], help="torch.compile modes to try")
    args = parser.parse_args()
    module = tcp if args.model == "tcp" else camera
    cache = cached(args.data, module.FEATURES, "train", args.split_name, workers=1)
    source = training.source(cache, module.inputs, 32)
    cuda = torch.device(args.device).type == "cuda"
    print(f"{args.model}: {len(source)} samples, {args.device}")
    print(f"DataLoader alone, batches of 32: {loader_rate(source, 32, 150, cuda):,.0f} samples/s")

    if args.model == "tcp":
        model = tcp.TCPPolicy(3, 6, 64).to(args.device)
        if cuda:
            model.trunk.to(memory_format=torch.channels_last)
        predict = tcp._predict
    else:
        model = camera.CameraPolicy().to(args.device)

        def predict(m, rows):  # type: ignore[no-untyped-def]
            return m(rows["images"], rows["vector"]), torch.zeros((), device=args.device)

    order = torch.randperm(len(source))
    reference = None
    for size in args.batch_sizes:
        rows = training.to_device(source.rows(order[:size]), args.device)
        rate = step_rate(model, predict, rows, args.device)
        reference = reference or rate
        print(f"step alone, batch {size}: {rate:,.0f} samples/s ({rate / reference:.2f}x)")
    rows = training.to_device(source.rows(order[: args.batch_sizes[0]]), args.device)
    for mode in args.compile:
        trunk = model.trunk if args.model == "tcp" else model.encoder
        started = time.perf_counter()
        compiled = torch.compile(trunk, mode=mode)
        if args.model == "tcp":
            model.trunk = compiled
        else:
            model.encoder = compiled
        step_rate(model, predict, rows, args.device, steps=1)  # compiles
        warm_up = time.perf_counter() - started
        rate = step_rate(model, predict, rows, args.device)
        print(
            f"step, trunk compiled ({mode}), batch {args.batch_sizes[0]}: {rate:,.0f} samples/s "
            f"({rate / reference:.2f}x; {warm_up:.0f} s to compile)"
        )
        if args.model == "tcp":
            model.trunk = trunk
        else:
            model.encoder = trunk


if __name__ == "__main__":
    main()
