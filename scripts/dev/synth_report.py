"""How often the synthetic source stages the behaviour it aims for, and how long a clip takes.

    python scripts/dev/synth_report.py --seeds 0 1 2 --clips 14

Prints, per targeted sub-scenario, how many clips showed it, and the seconds per clip.
"""

from __future__ import annotations

import argparse
import time
from collections import Counter

from drivee2e_data.sources import synthetic


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--clips", type=int, default=14)
    args = parser.parse_args()
    aimed, hit, agents = Counter(), Counter(), []
    start = time.perf_counter()
    for seed in args.seeds:
        for _, scenario in synthetic.generate(args.clips, seed):
            target = scenario.metadata["target_sub_scenario"]
            aimed[target] += 1
            hit[target] += scenario.behavior.sub_scenario.value == target
            agents.append(len(scenario.tracks))
    elapsed = time.perf_counter() - start
    total = sum(aimed.values())
    print("| targeted | clips | staged as targeted |")
    print("|---|---|---|")
    for target in synthetic.TARGET_ORDER:
        if aimed[target.value]:
            print(f"| {target.value} | {aimed[target.value]} | {hit[target.value]} |")
    print(f"| all | {total} | {sum(hit.values())} ({100 * sum(hit.values()) / total:.0f}%) |")
    print(
        f"\n{elapsed / total:.2f} s per clip on this machine; agents per clip: "
        f"min {min(agents)}, median {sorted(agents)[len(agents) // 2]}, max {max(agents)}"
    )


if __name__ == "__main__":
    main()
