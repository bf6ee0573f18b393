"""The closed-loop benchmark: `evaluate`."""

from __future__ import annotations

import argparse
from pathlib import Path

from tqdm import tqdm

from drivee2e_data import splits
from drivee2e_data.agents import registry
from drivee2e_data.agents.registry import AGENTS
from drivee2e_data.cli.arguments import (
    _split_options,
    _workers,
)
from drivee2e_data.curation.occlusion import Variant
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.evaluate import results, runner
from drivee2e_data.sim.world import RENDERERS


def add_evaluate(commands) -> None:  # type: ignore[no-untyped-def]
    """The `evaluate` command's arguments."""
    evaluate = commands.add_parser(
        "evaluate", help="closed loop: drive each clip of a split with an agent; SR and DS"
    )
    evaluate.add_argument("data", type=Path, help="data root (curated; logs for --variant)")
    _split_options(evaluate, "val")
    evaluate.add_argument(
        "--agent", default="expert", help=f"{', '.join(AGENTS)}, or MODULE:CLASS (default expert)"
    )
    evaluate.add_argument(
        "--agent-cmd", default=None, metavar="CMD", help="run the agent as this child process "
        "(its own environment; protocol in drivee2e_data/evaluate/agent_client.py)",
    )  # fmt: skip
    evaluate.add_argument("--checkpoint", type=Path, default=None, help="the agent's checkpoint")
    evaluate.add_argument(
        "--reactive", action="store_true", help="vehicles follow their paths with IDM"
    )
    evaluate.add_argument("--variant", choices=[v.value for v in Variant], default="complete")
    evaluate.add_argument(
        "--min-speed",
        action="store_true",
        help="apply LB2's minimum-speed penalty (off by default)",
    )
    evaluate.add_argument(
        "--workers",
        type=_workers,
        default=1,
        help="processes (default 1); auto: one per core for agents that read cameras (their "
        "renderers spread over the GPUs), a few for agents that read none",
    )
    evaluate.add_argument(
        "--policy-server",
        choices=("auto", "on", "off"),
        default="auto",
        help="run a camera agent's network once per GPU for all workers, batched (auto: where "
        "torch sees a GPU and several workers run; on: also on the CPU)",
    )
    evaluate.add_argument(
        "--record",
        nargs="?",
        const="mcap",
        default="",
        choices=("mcap", "mp4"),
        help="write RUN/records/<clip>.mcap (the episode for Foxglove; the default kind) or "
        "<clip>.mp4 (the front camera beside the top view with the driven and logged paths)",
    )
    evaluate.add_argument(
        "--exact-images",
        action="store_true",
        help="draw camera agents' images at the collection size and JPEG them, as the logs "
        "(default: drawn at the size the agent reads, docs/closedloop.md)",
    )
    evaluate.add_argument("--seed", type=int, default=0)
    evaluate.add_argument("--renderer", choices=RENDERERS, default="auto")
    evaluate.add_argument(
        "--step-timeout",
        type=float,
        default=30.0,
        help="seconds an --agent-cmd child may take a step",
    )
    evaluate.add_argument(
        "--out",
        type=Path,
        default=None,
        help="run folder (default DATA/results/AGENT-SPLIT-VARIANT)",
    )
    evaluate.add_argument("--only", nargs="+", default=None, metavar="ID", help="these clips only")


def run_evaluate(args: argparse.Namespace) -> int:
    # a bad name or checkpoint fails here, once: the checkpoint read and its kind checked, the
    # network left to what runs it (a policy server, the workers); built here as well, it started
    # CUDA in this process for nothing, about a second before the pool could start (H200 host)
    agent = None if args.agent_cmd else registry.build(args.agent, args.checkpoint, network=False)
    options = runner.EvaluationOptions(
        agent=args.agent,
        checkpoint=str(args.checkpoint) if args.checkpoint else None,
        agent_cmd=args.agent_cmd,
        reactive=args.reactive,
        variant=args.variant,
        min_speed=args.min_speed,
        record=args.record,
        seed=args.seed,
        renderer=args.renderer,
        step_timeout_s=args.step_timeout,
        exact_images=args.exact_images,
        policy_server=args.policy_server,
    )
    manifest = splits.split_path(args.data, args.split_name)
    if not manifest.is_file():
        raise DriveE2EError(f"{manifest}: no split manifest; run drivee2e split {args.data}")
    clips = splits.scenario_ids(manifest, args.split)
    if args.only:
        clips = [c for c in clips if c in set(args.only)]
    if not clips:
        raise DriveE2EError(f"{manifest}: split {args.split!r} has no clips to evaluate")
    workers = args.workers
    if workers == "auto":
        reads = () if agent is None else tuple(agent.sensors)
        workers = runner.auto_workers(len(clips), bool(reads) or bool(args.agent_cmd))
        print(f"evaluate: {workers} workers (--workers auto)")
    out = args.out or args.data / runner.RESULTS_FOLDER / runner.run_name(options, args.split)
    with tqdm(total=len(clips), unit="episode", desc="evaluating", disable=None) as bar:
        bar.update(len(clips) - len(runner.prepare_run(args.data, out, options, clips)))

        def done(row: dict) -> None:
            bar.update(1)
            if row.get("status") in ("error", "agent_failed"):
                bar.write(f"{row['scenario_id']}: {row.get('failure', '')}")

        rows = runner.evaluate(
            args.data, clips, options, out, workers, done, registry.build, probe=agent
        )
    summary = results.write_results(out, rows, options)
    print(results.markdown_table(summary), end="")
    print(f"results: {out}/ (episodes.parquet, summary.json, table.md)")
    return 0
