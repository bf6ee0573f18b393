"""Markdown tables of open-loop results from `scripts/openloop_baselines.sh` outputs.

    python scripts/results_table.py DATA [--split val]

    python scripts/results_table.py DATA [--split val] --closedloop [--variant V] [--reactive]

Prints the paper's open-loop shape (L2 at 1 s, 2 s, their mean, 3 s, collision rate at 3 s)
per model in both conventions, then the per-category L2 (stp3) of each model. With
`--closedloop`, the paper's Table 3 shape instead (open-loop L2 stp3 1 s, 2 s, avg; closed-loop
SR, DS, RC, seconds per scene) from `drivee2e evaluate`'s run folders, and SR per behaviour.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

MODELS = ("constant-velocity", "admlp", "camera")
AGENTS = ("expert", "constant-velocity", "admlp", "camera")


def cell(value: float | None, percent: bool = False) -> str:
    if value is None or math.isnan(value):
        return "-"
    return f"{100 * value:.2f}%" if percent else f"{value:.2f}"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("data", type=Path)
    parser.add_argument("--split", default="val")
    parser.add_argument("--closedloop", action="store_true")
    parser.add_argument("--variant", default="complete")
    parser.add_argument("--reactive", action="store_true")
    args = parser.parse_args()
    if args.closedloop:
        closed_loop(args)
        return
    folder = args.data / "results" / "openloop"
    models = [m for m in MODELS if (folder / f"{m}_{args.split}_stp3.json").is_file()]
    results = {
        (model, convention): json.loads(
            (folder / f"{model}_{args.split}_{convention}.json").read_text()
        )["results"]
        for model in models
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
    print("| category | samples | " + " | ".join(f"{m} L2 avg (1 s, 2 s)" for m in models) + " |")
    print("|---|---|" + "---|" * len(models))
    for category in categories:
        cells = [cell(results[(m, "stp3")].get(category, {}).get("l2_avg_1_2s")) for m in models]
        samples = results[(models[0], "stp3")].get(category, {}).get("samples", 0)
        print(f"| {category} | {samples} | " + " | ".join(cells) + " |")


def closed_loop(args: argparse.Namespace) -> None:
    openloop = args.data / "results" / "openloop"
    suffix = f"{args.split}-{args.variant}" + ("-reactive" if args.reactive else "")
    summaries = {}
    for agent in AGENTS:
        path = args.data / "results" / f"{agent}-{suffix}" / "summary.json"
        if path.is_file():
            summaries[agent] = json.loads(path.read_text())
    print("| model | L2 1 s | L2 2 s | L2 avg | SR % | DS | RC % | collisions/km | s/scene |")
    print("|---|---|---|---|---|---|---|---|---|")
    for agent, summary in summaries.items():
        l2 = {"l2_1s": 0.0, "l2_2s": 0.0, "l2_avg_1_2s": 0.0} if agent == "expert" else {}
        path = openloop / f"{agent}_{args.split}_stp3.json"
        if path.is_file():
            l2 = json.loads(path.read_text())["results"]["all"]
        collisions = sum(
            summary["infractions_per_km"][k]
            for k in ("collision_pedestrian", "collision_vehicle", "collision_static")
        )
        print(
            f"| {agent} | {cell(l2.get('l2_1s'))} | {cell(l2.get('l2_2s'))} | "
            f"{cell(l2.get('l2_avg_1_2s'))} | {summary['success_rate']:.1f} | "
            f"{summary['driving_score']:.2f} | {summary['route_completion']:.1f} | "
            f"{collisions:.2f} | {summary['seconds_per_scene']:.1f} |"
        )
    categories = sorted({c for s in summaries.values() for c in s["success_rate_per_category"]})
    print()
    print("| category | episodes | " + " | ".join(f"{a} SR %" for a in summaries) + " |")
    print("|---|---|" + "---|" * len(summaries))
    for category in categories:
        first = next(iter(summaries.values()))
        episodes = first["episodes_per_category"].get(category, 0)
        rates = [
            f"{s['success_rate_per_category'].get(category, float('nan')):.0f}"
            for s in summaries.values()
        ]
        print(f"| {category} | {episodes} | " + " | ".join(rates) + " |")


if __name__ == "__main__":
    main()
