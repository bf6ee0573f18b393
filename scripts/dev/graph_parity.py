"""A closed-loop network's forward replayed as a CUDA graph against the eager forward (the
reference), on a GPU: the plans of both for the same random inputs (max difference; equal bits
expected) and the time a forward takes, batch by batch, as a policy server runs it
(`agents/inference.py`).

    python scripts/dev/graph_parity.py [--model tcp] [--checkpoint C] [--batches 1 16 40]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from drivee2e_data.agents import camera, tcp
from drivee2e_data.agents.inference import NetworkRunner


def network(model: str, checkpoint: Path | None) -> torch.nn.Module:
    if checkpoint is not None:
        loaded, _ = (tcp if model == "tcp" else camera).load(checkpoint)
        assert loaded is not None
        return loaded
    torch.manual_seed(0)
    built = tcp.TCPPolicy() if model == "tcp" else camera.CameraPolicy()
    return built.eval()


def timed(runner: NetworkRunner, inputs: list[tuple[np.ndarray, np.ndarray]]) -> list[float]:
    seconds = []
    for images, vector in inputs:
        began = time.perf_counter()
        runner.plans(images, vector)  # returns on the host: the GPU has finished
        seconds.append(time.perf_counter() - began)
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", choices=("tcp", "camera"), default="tcp")
    parser.add_argument("--checkpoint", type=Path)
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 16, 40])
    parser.add_argument("--repeats", type=int, default=50)
    args = parser.parse_args()
    model = network(args.model, args.checkpoint).to("cuda")
    width, height = tcp.INPUT_SIZE if args.model == "tcp" else camera.INPUT_SIZE
    generator = np.random.default_rng(0)
    print(f"{args.model} on {torch.cuda.get_device_name()}; eager is the reference")
    for batch in args.batches:
        inputs = [
            (
                generator.integers(0, 256, (batch, 3, 3, height, width), dtype=np.uint8),
                generator.standard_normal((batch, 6)).astype(np.float32),
            )
            for _ in range(args.repeats)
        ]
        eager = NetworkRunner(model, "cuda", graphs=False)
        graphed = NetworkRunner(model, "cuda", graphs=True)
        differences = [
            float(np.abs(eager.plans(*pair) - graphed.plans(*pair)).max()) for pair in inputs
        ]
        eager_s = statistics.median(timed(eager, inputs))
        graphed_s = statistics.median(timed(graphed, inputs))
        print(
            f"batch {batch:3d}: max |graph - eager| {max(differences):.3g} m "
            f"({sum(d == 0.0 for d in differences)}/{len(differences)} equal); "
            f"eager {eager_s * 1e3:.2f} ms, graph {graphed_s * 1e3:.2f} ms, "
            f"ratio {graphed_s / eager_s:.3f}"
        )


if __name__ == "__main__":
    main()
