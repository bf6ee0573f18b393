"""Benchmark v1's tables and figure from a `scripts/benchmark.sh OUT` folder.

    python scripts/benchmark_report.py OUT [--figure PNG]

Prints (and writes to OUT/report.md): the paper's Table 3 shape for every model at the largest
training size (open-loop L2 at 1 s, 2 s and their mean in the stp3 convention, collisions at
3 s; closed-loop SR, DS, RC, seconds per scene), Success Rate per behaviour category, every
(model, size) row, the run-to-run spread of the models trained with two seeds, Kendall's tau
between the open-loop ranking (L2, lower first) and the closed-loop ranking (DS, higher first)
over the learned models and sizes, and the time each stage took. Draws L2 and DS against the
number of training clips for each baseline (OUT/scaling.png unless `--figure`).
"""

from __future__ import annotations

import argparse
import json
import math
import re
from itertools import combinations
from pathlib import Path

LEARNED = ("admlp", "camera", "tcp")
RUN = re.compile(r"^(?P<model>[a-z-]+)-(?P<size>\d+)-seed(?P<seed>\d+)$")


def kendall_tau(first: list[float], second: list[float]) -> float:
    """Kendall's tau-b of two paired samples (ties counted as in tau-b)."""
    concordant = discordant = ties_first = ties_second = 0
    for i, j in combinations(range(len(first)), 2):
        a, b = first[i] - first[j], second[i] - second[j]
        if a == 0 and b == 0:
            continue
        if a == 0:
            ties_first += 1
        elif b == 0:
            ties_second += 1
        elif (a > 0) == (b > 0):
            concordant += 1
        else:
            discordant += 1
    denominator = math.sqrt((concordant + discordant + ties_first) *
                            (concordant + discordant + ties_second))  # fmt: skip
    return (concordant - discordant) / denominator if denominator else float("nan")


def read_runs(out: Path) -> dict[str, dict]:
    """Each run folder's closed-loop summary and open-loop results, by run name."""
    runs = {}
    for summary_path in sorted((out / "runs").glob("*/summary.json")):
        name = summary_path.parent.name
        row = {"closed": json.loads(summary_path.read_text())}
        for convention in ("stp3", "uniad"):
            path = out / "openloop" / f"{name}_{convention}.json"
            if path.is_file():
                row[convention] = json.loads(path.read_text())["results"]["all"]
        match = RUN.match(name)
        row["model"] = match["model"] if match else name
        row["size"] = int(match["size"]) if match else None
        row["seed"] = int(match["seed"]) if match else None
        runs[name] = row
    return runs


def number(value: float | None, digits: int = 2) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else \
        f"{value:.{digits}f}"  # fmt: skip


def table_row(name: str, row: dict) -> str:
    closed, l2 = row["closed"], row.get("stp3", {})
    collision = l2.get("collision_3s")
    return (f"| {name} | {number(l2.get('l2_1s'))} | {number(l2.get('l2_2s'))} | "
            f"{number(l2.get('l2_avg_1_2s'))} | "
            f"{number(None if collision is None else 100 * collision)} | "
            f"{closed['success_rate']:.1f} | {closed['driving_score']:.2f} | "
            f"{closed['route_completion']:.1f} | {closed['seconds_per_scene']:.1f} |")  # fmt: skip


HEADER = ("| model | L2 1 s (m) | L2 2 s | L2 avg | collisions 3 s % | SR % | DS | RC % | s/scene |\n"
          "|---|---|---|---|---|---|---|---|---|")  # fmt: skip


def report(out: Path) -> tuple[str, dict]:
    runs = read_runs(out)
    sizes = sorted({r["size"] for r in runs.values() if r["size"] is not None})
    largest = sizes[-1] if sizes else None
    lines = [f"## Benchmark v1: {out}", ""]
    lines += [f"### Every model at the largest training size ({largest} clips), val", "", HEADER]
    for name in ("expert", "constant-velocity"):
        if name in runs:
            lines.append(table_row(name, runs[name]))
    for model in LEARNED:
        name = f"{model}-{largest}-seed0"
        if name in runs:
            lines.append(table_row(f"{model} ({largest} clips)", runs[name]))
    lines += ["", "### Success Rate per behaviour category (largest size), %", ""]
    shown = [n for n in ("expert", "constant-velocity") if n in runs]
    shown += [f"{m}-{largest}-seed0" for m in LEARNED if f"{m}-{largest}-seed0" in runs]
    categories = sorted({c for n in shown for c in runs[n]["closed"]["success_rate_per_category"]})
    lines.append("| category | episodes | " + " | ".join(shown) + " |")
    lines.append("|---|---|" + "---|" * len(shown))
    for category in categories:
        episodes = runs[shown[0]]["closed"]["episodes_per_category"].get(category, 0)
        rates = [number(runs[n]["closed"]["success_rate_per_category"].get(category), 0)
                 for n in shown]  # fmt: skip
        lines.append(f"| {category} | {episodes} | " + " | ".join(rates) + " |")
    lines += ["", "### Every model and size (seed 0)", "", HEADER]
    for model in LEARNED:
        for size in sizes:
            name = f"{model}-{size}-seed0"
            if name in runs:
                lines.append(table_row(f"{model} {size}", runs[name]))
    spread = [(m, s) for m in LEARNED for s in sizes
              if f"{m}-{s}-seed0" in runs and f"{m}-{s}-seed1" in runs]  # fmt: skip
    if spread:
        lines += ["", "### Two training seeds", "", HEADER]
        for model, size in spread:
            for seed in (0, 1):
                lines.append(table_row(f"{model} {size} seed {seed}",
                                       runs[f"{model}-{size}-seed{seed}"]))  # fmt: skip
    learned = [r for r in runs.values() if r["model"] in LEARNED and r["seed"] == 0 and "stp3" in r]
    tau = kendall_tau([-r["stp3"]["l2_avg_1_2s"] for r in learned],
                      [r["closed"]["driving_score"] for r in learned])  # fmt: skip
    lines += ["", f"Kendall's tau between the open-loop ranking (L2 avg, lower better) and the "
              f"closed-loop ranking (DS) over {len(learned)} (model, size) pairs: {tau:.2f}"]  # fmt: skip
    times_path = out / "times.tsv"
    if times_path.is_file():
        lines += ["", "### Time per stage", "", "| stage | s |", "|---|---|"]
        for line in times_path.read_text().splitlines():
            if line.startswith("#"):  # a run's start (a resumed run appends its own)
                lines.append(f"| *{line.lstrip('# ')}* | |")
                continue
            stage, seconds = line.split("\t")
            lines.append(f"| {stage} | {seconds} |")
    return "\n".join(lines) + "\n", {"runs": runs, "sizes": sizes, "tau": tau}


def figure(data: dict, path: Path) -> None:
    """L2 (stp3, avg of 1 s and 2 s) and DS against the number of training clips, per model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs, sizes = data["runs"], data["sizes"]
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    for model in LEARNED:
        points = [(s, runs[f"{model}-{s}-seed0"]) for s in sizes if f"{model}-{s}-seed0" in runs]
        if not points:
            continue
        x = [s for s, _ in points]
        left.plot(x, [r.get("stp3", {}).get("l2_avg_1_2s", math.nan) for _, r in points], "o-",
                  label=model)  # fmt: skip
        right.plot(x, [r["closed"]["driving_score"] for _, r in points], "o-", label=model)
    for name, style in (("constant-velocity", ":"), ("expert", "--")):
        if name in runs and sizes:
            right.axhline(runs[name]["closed"]["driving_score"], linestyle=style, color="grey",
                          label=name)  # fmt: skip
            if name != "expert" and "stp3" in runs[name]:
                left.axhline(runs[name]["stp3"]["l2_avg_1_2s"], linestyle=style, color="grey",
                             label=name)  # fmt: skip
    for axis, title in ((left, "open loop: L2 avg 1-2 s (m), lower is better"),
                        (right, "closed loop: Driving Score, higher is better")):  # fmt: skip
        axis.set_xscale("log", base=2)
        axis.set_xticks(sizes, [str(s) for s in sizes])
        axis.set_xlabel("training clips")
        axis.set_title(title, fontsize=10)
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--figure", type=Path, default=None)
    args = parser.parse_args()
    text, data = report(args.out)
    print(text)
    (args.out / "report.md").write_text(text)
    figure(data, args.figure or args.out / "scaling.png")


if __name__ == "__main__":
    main()
