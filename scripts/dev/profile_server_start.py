"""What a policy server's start costs, step by step, in a process forked as the pool forks it
(torch imported before the fork, CUDA not started): CUDA's start on the device, the agent built
with its network there (checkpoint read, network made, moved), then its first batch of the
agent's example inputs (`policy_server.warm_up`, as a server runs before its first request: a
CUDA graph recorded at `BATCH_ROWS` rows) and a second (replayed). Printed in seconds; the first
batch is what the first steps of every episode wait for when the server records it at its
first request. Reference: the same steps with CUDA started first (`--cuda-first`, default) or
after the build (`--cuda-last`); `--profile` prints the build's cProfile (most cumulative).

    python scripts/dev/profile_server_start.py --agent tcp --checkpoint CKPT [--device cuda:0]
"""

from __future__ import annotations

import argparse
import cProfile
import io
import multiprocessing
import os
import pstats
import time
from pathlib import Path


def _steps(agent: str, checkpoint: str, device: str, cuda_first: bool, out) -> None:
    import torch

    from drivee2e_data.agents import registry
    from drivee2e_data.evaluate.policy_server import AGENT_DEVICE_VARIABLE, BATCH_ROWS, warm_up

    os.environ[AGENT_DEVICE_VARIABLE] = device
    times: list[tuple[str, float]] = []

    def mark(label: str, began: float) -> float:
        now = time.perf_counter()
        times.append((label, now - began))
        return now

    began = time.perf_counter()
    if cuda_first:
        if device.startswith("cuda"):
            torch.cuda.set_device(device)
        torch.zeros(1, device=device)
        began = mark("CUDA started (a tensor on the device)", began)
    profile = cProfile.Profile()
    profile.enable()
    built = registry.build(agent, Path(checkpoint))
    profile.disable()
    began = mark("the agent built with its network", began)
    text = io.StringIO()
    pstats.Stats(profile, stream=text).sort_stats("cumulative").print_stats(14)
    if not cuda_first:
        torch.zeros(1, device=device)
        began = mark("CUDA started after", began)
    warm_up(built, BATCH_ROWS)  # as a server does before its first request
    began = mark(f"the first batch ({BATCH_ROWS} rows: warm-up and the graph's recording)", began)
    warm_up(built, BATCH_ROWS)
    mark("the second batch (replayed)", began)
    out.put((times, text.getvalue()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--agent", default="tcp")
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--device", default="cuda:0")
    parser.add_argument("--cuda-last", action="store_true")
    parser.add_argument("--profile", action="store_true", help="the build's cProfile too")
    args = parser.parse_args()
    import importlib

    import torch  # noqa: F401 (imported before the fork, as the pool's server has it)

    from drivee2e_data.agents import registry

    # the agent's module too, as the command's entry point has the pool's server import it
    importlib.import_module(registry.AGENTS.get(args.agent, args.agent).partition(":")[0])

    context = multiprocessing.get_context("fork")
    out = context.Queue()
    for repeat in range(2):
        process = context.Process(target=_steps, args=(args.agent, args.checkpoint, args.device,
                                                       not args.cuda_last, out))  # fmt: skip
        started = time.perf_counter()
        process.start()
        times, report = out.get()
        process.join()
        print(
            f"## run {repeat + 1} (fork to the second batch's end: "
            f"{time.perf_counter() - started:.2f} s)"
        )
        for label, seconds in times:
            print(f"| {label} | {seconds:.3f} s |")
        if args.profile:
            print(report)


if __name__ == "__main__":
    main()
