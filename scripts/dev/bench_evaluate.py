"""Closed-loop cost: seconds per scene of each agent (scaled to a 20 s clip and as a multiple of
real time), peak memory per evaluation process, and the suite's wall time with N workers
against one worker (the reference), in one run.

    python scripts/dev/bench_evaluate.py DATA [--split val] [--admlp CKPT] [--camera CKPT]
                                          [--workers 2] [--suite-agent camera]

DATA is a curated data root with a split manifest. Every measurement evaluates into a fresh
temporary run folder, so nothing is resumed. The expert and AD-MLP render nothing; the camera
policy renders its three front cameras at the size its training data was collected at.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from drivee2e_data import splits, store
from drivee2e_data.agents import registry
from drivee2e_data.evaluate import runner

REFERENCE_CLIP_S = 20.0


def run(
    data: Path, clips: list[str], agent: str, checkpoint: str | None, workers: int
) -> tuple[float, list[dict]]:
    options = runner.EvaluationOptions(agent=agent, checkpoint=checkpoint)
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        rows = runner.evaluate(data, clips, options, Path(folder) / "run", workers,
                               agent_factory=registry.build)  # fmt: skip
        return time.perf_counter() - start, rows


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("data", type=Path)
    parser.add_argument("--split", default="val")
    parser.add_argument("--admlp", default=None, help="AD-MLP checkpoint")
    parser.add_argument("--camera", default=None, help="camera policy checkpoint")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--suite-agent", default="camera")
    args = parser.parse_args()
    clips = splits.scenario_ids(splits.split_path(args.data, "default"), args.split)
    durations = {c: store.read_scenario(args.data, c).duration_s for c in clips}
    agents = [("expert", None)]
    agents += [("admlp", args.admlp)] if args.admlp else []
    agents += [("camera", args.camera)] if args.camera else []
    print(
        f"{len(clips)} clips of split {args.split}, {np.mean(list(durations.values())):.1f} s each on average"
    )
    print("| agent | s/scene | s per 20 s clip | x real time | peak RSS per process |")
    print("|---|---|---|---|---|")
    for agent, checkpoint in agents:
        _, rows = run(args.data, clips, agent, checkpoint, 1)
        per_scene = float(np.mean([r["wall_seconds"] for r in rows]))
        per_second = float(np.mean([r["wall_seconds"] / r["sim_seconds"] for r in rows]))
        peak = max(r["peak_rss_bytes"] for r in rows) / 2**30
        print(
            f"| {agent} | {per_scene:.2f} | {per_second * REFERENCE_CLIP_S:.2f} | "
            f"{per_second:.3f} | {peak:.2f} GiB |"
        )
    suite = {"admlp": args.admlp, "camera": args.camera, "expert": None}[args.suite_agent]
    one, _ = run(args.data, clips, args.suite_agent, suite, 1)
    many, rows = run(args.data, clips, args.suite_agent, suite, args.workers)
    peak = max(r["peak_rss_bytes"] for r in rows) / 2**30
    print(
        f"\nsuite ({args.suite_agent}, {len(clips)} clips): 1 worker {one:.1f} s (reference), "
        f"{args.workers} workers {many:.1f} s: {one / many:.2f}x faster; "
        f"peak RSS per worker {peak:.2f} GiB"
    )


if __name__ == "__main__":
    main()
