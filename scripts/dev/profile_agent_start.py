"""What an evaluation worker's first scene pays for its agent when every worker starts at once,
as at a pool's start: N spawned processes, released together, each timing the steps of
`runner._agent_for` for a served agent (the network stays on the policy server) and two ways
of reading the checkpoint. Reference: the same steps in one process alone.

    python scripts/dev/profile_agent_start.py --agent tcp --checkpoint CKPT [--processes 16]
"""

from __future__ import annotations

import argparse
import importlib
import multiprocessing
import time
from pathlib import Path

STEPS = ("import torch and cv2", "import the agent's module", "read the checkpoint",
         "read the checkpoint (mmap)", "build without network")  # fmt: skip


def _steps(agent: str, checkpoint: str, barrier, results) -> None:
    barrier.wait()
    times = []
    start = time.perf_counter()
    import cv2
    import torch

    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    times.append(time.perf_counter() - start)
    from drivee2e_data.agents import registry

    start = time.perf_counter()
    module, _, _ = registry.AGENTS.get(agent, agent).partition(":")
    importlib.import_module(module)
    times.append(time.perf_counter() - start)
    start = time.perf_counter()
    torch.load(checkpoint, map_location="cpu", weights_only=True)
    times.append(time.perf_counter() - start)
    start = time.perf_counter()
    torch.load(checkpoint, map_location="cpu", weights_only=True, mmap=True)
    times.append(time.perf_counter() - start)
    start = time.perf_counter()
    registry.build(agent, Path(checkpoint), network=False)
    times.append(time.perf_counter() - start)
    results.put(times)


def run(agent: str, checkpoint: str, processes: int) -> list[list[float]]:
    context = multiprocessing.get_context("spawn")
    barrier, results = context.Barrier(processes), context.Queue()
    workers = [context.Process(target=_steps, args=(agent, checkpoint, barrier, results))
               for _ in range(processes)]  # fmt: skip
    for worker in workers:
        worker.start()
    rows = [results.get() for _ in workers]
    for worker in workers:
        worker.join()
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--agent", default="tcp")
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--processes", type=int, default=16)
    args = parser.parse_args()
    alone = run(args.agent, args.checkpoint, 1)[0]
    together = run(args.agent, args.checkpoint, args.processes)
    print(f"| step | alone s | {args.processes} at once: mean s | slowest s |")
    print("|---|---|---|---|")
    for index, step in enumerate(STEPS):
        values = [row[index] for row in together]
        print(f"| {step} | {alone[index]:.2f} | {sum(values) / len(values):.2f} "
              f"| {max(values):.2f} |")  # fmt: skip


if __name__ == "__main__":
    main()
