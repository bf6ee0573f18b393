"""Markdown tables of open-loop results from `scripts/openloop_baselines.sh` outputs.

    python scripts/results_table.py DATA [--split val]

Prints the paper's open-loop shape (L2 at 1 s, 2 s, their mean, 3 s, collision rate at 3 s)
per model in both conventions, then the per-category L2 (stp3) of each model.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

MODELS = ("constant-velocity", "admlp")


def cell(value: float | None, percent: bool = False) -> str:
    if value is None or math.isnan(value):
        return "-"
    return f"{100 * value:.2f}%" if percent else f"{value:.2f}"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("data", type=Path)
    parser.add_argument("--split", default="val")
    args = parser.parse_args()
    folder = args.data / "results" / "openloop"
    results = {
        (model, convention): json.loads(
            (folder / f"{model}_{args.split}_{convention}.json").read_text()
        )["results"]
        for model in MODELS
        for convention in ("stp3", "uniad")
    }
    print(
        "| model | convention | samples | L2 1 s | L2 2 s | avg (1 s, 2 s) | L2 3 s | collision 3 s |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for (model, convention), table in results.items():
        row = table["all"]
        print(
            f"| {model} | {convention} | {row['samples']} | {cell(row['l2_1s'])} | "
            f"{cell(row['l2_2s'])} | {cell(row['l2_avg_1_2s'])} | {cell(row['l2_3s'])} | "
            f"{cell(row.get('collision_3s'), percent=True)} |"
        )
    categories = sorted({c for table in results.values() for c in table if c != "all"})
    print()
    print("| category | samples | " + " | ".join(f"{m} L2 avg (1 s, 2 s)" for m in MODELS) + " |")
    print("|---|---|" + "---|" * len(MODELS))
    for category in categories:
        cells = [cell(results[(m, "stp3")].get(category, {}).get("l2_avg_1_2s")) for m in MODELS]
        samples = results[(MODELS[0], "stp3")].get(category, {}).get("samples", 0)
        print(f"| {category} | {samples} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
