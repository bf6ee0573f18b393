"""cProfile of closed-loop episodes in this one process (no pool, no policy server: the agent's
network on its own device): where a step's time goes when nothing else competes for the host.

    python scripts/dev/profile_evaluate.py DATA --agent tcp --checkpoint CKPT [--clips 2]
        [--split all] [--top 30]

Prints each episode's breakdown (scripts/dev/closedloop_breakdown.py's columns) and the
functions with the most own time, then the most cumulative time, over all the episodes.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import tempfile
import time
from pathlib import Path

from drivee2e_data import splits
from drivee2e_data.agents import registry
from drivee2e_data.evaluate import runner


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--agent", default="tcp")
    parser.add_argument("--checkpoint", default=None)
    parser.add_argument("--split", default="all")
    parser.add_argument("--clips", type=int, default=2)
    parser.add_argument("--top", type=int, default=30)
    args = parser.parse_args()
    manifest = splits.split_path(args.data, "default")
    clips = splits.scenario_ids(manifest, args.split)[: args.clips]
    options = runner.EvaluationOptions(agent=args.agent, checkpoint=args.checkpoint)
    # the agent's module and its first episode's set-up outside the profile
    with tempfile.TemporaryDirectory() as folder:
        runner.evaluate(args.data, clips[:1], options, Path(folder) / "warm", 1,
                        agent_factory=registry.build)  # fmt: skip
        profile = cProfile.Profile()
        start = time.perf_counter()
        profile.enable()
        rows = runner.evaluate(args.data, clips, options, Path(folder) / "run", 1,
                               agent_factory=registry.build)  # fmt: skip
        profile.disable()
        print(f"{len(clips)} episodes in {time.perf_counter() - start:.1f} s (profiled)")
    for row in rows:
        steps = max(row["steps"], 1)
        print(f"{row['scenario_id']}: {row['steps']} steps, wall {row['wall_seconds']:.2f} s, "
              f"episode {row['episode_seconds']:.2f}, observe "
              f"{1000 * row['observe_seconds'] / steps:.1f} ms a step, agent "
              f"{1000 * row['agent_seconds'] / steps:.1f} ms a step")  # fmt: skip
    stats = pstats.Stats(profile)
    stats.sort_stats("tottime").print_stats(args.top)
    stats.sort_stats("cumulative").print_stats(args.top)


if __name__ == "__main__":
    main()
