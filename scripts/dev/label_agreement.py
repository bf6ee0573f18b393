"""Agreement of the behaviour labeller with the synthetic source's staged behaviour.

    python scripts/dev/label_agreement.py --seeds 0 1 2 --clips 14

Synthesises the clips in memory, labels each staged ego from its scenario and map alone, and
prints per-category precision and recall (staged behaviour as the truth) and the confusions.
"""

from __future__ import annotations

import argparse
from collections import Counter

from drivee2e_data.curation import behavior
from drivee2e_data.scenario import BehaviorCategory
from drivee2e_data.sources import synthetic


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--clips", type=int, default=14)
    args = parser.parse_args()
    pairs = []
    for seed in args.seeds:
        for intersection_map, scenario in synthetic.generate(args.clips, seed):
            labelled = behavior.label(scenario, intersection_map)
            pairs.append((scenario.behavior.sub_scenario, labelled))
    print("| category | staged | labelled | agree | precision | recall |")
    print("|---|---|---|---|---|---|")
    for category in BehaviorCategory:
        staged = sum(t.category == category for t, _ in pairs)
        labelled = sum(p.category == category for _, p in pairs)
        agree = sum(t.category == category == p.category for t, p in pairs)
        precision = f"{100 * agree / labelled:.0f}%" if labelled else "-"
        recall = f"{100 * agree / staged:.0f}%" if staged else "-"
        print(f"| {category.value} | {staged} | {labelled} | {agree} | {precision} | {recall} |")
    categories = sum(t.category == p.category for t, p in pairs)
    exact = sum(t == p for t, p in pairs)
    print(
        f"\n{len(pairs)} clips: category agreement {100 * categories / len(pairs):.0f}%, "
        f"sub-scenario agreement {100 * exact / len(pairs):.0f}%"
    )
    confusions = Counter((t.value, p.value) for t, p in pairs if t != p)
    if confusions:
        print(
            "confusions (staged -> labelled): "
            + ", ".join(f"{a} -> {b} x{n}" for (a, b), n in confusions.most_common())
        )


if __name__ == "__main__":
    main()
