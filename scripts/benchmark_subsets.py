"""Nested, behaviour-stratified training subsets of a split manifest, and a fixed val subset, for
Benchmark v1 (`scripts/benchmark.sh`).

    python scripts/benchmark_subsets.py MANIFEST --sizes 25 50 100 200 --val 40 --out DIR [--seed 0]

Orders the manifest's train clips so that every prefix holds each behaviour category in about
its share of the train split (within a category the clips are shuffled with `--seed`; a clip's
place is its quantile inside its category), likewise the val clips. Writes `DIR/train-N.csv` for
each size N: the first N train clips (split train) and the first `--val` val clips (split val),
the same val clips for every size, so every model is scored on the same clips; and
`DIR/clips.txt`, the clips any of them needs (to synthesise and collect). Subsets are nested:
train-25 lies inside train-50. Same manifest and seed, same files.
"""

from __future__ import annotations

import argparse
import csv
from collections import defaultdict
from pathlib import Path

import numpy as np


def stratified_order(rows: list[dict[str, str]], seed: int) -> list[dict[str, str]]:
    """`rows` ordered so that every prefix holds each category in about its share: clips shuffled
    inside their category, then sorted by their quantile there (ties: category name)."""
    by_category: dict[str, list[dict[str, str]]] = defaultdict(list)
    for row in sorted(rows, key=lambda r: r["scenario_id"]):
        by_category[row["category"]].append(row)
    keyed = []
    for category, members in sorted(by_category.items()):
        rng = np.random.default_rng([seed, sum(category.encode())])
        for place, index in enumerate(rng.permutation(len(members))):
            keyed.append(((place + 0.5) / len(members), category, members[int(index)]))
    keyed.sort(key=lambda item: (item[0], item[1]))
    return [row for _, _, row in keyed]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("manifest", type=Path)
    parser.add_argument("--sizes", type=int, nargs="+", required=True)
    parser.add_argument("--val", type=int, required=True, help="val clips every model is scored on")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    with open(args.manifest, newline="") as stream:
        rows = list(csv.DictReader(stream))
    fields = list(rows[0])
    train = stratified_order([r for r in rows if r["split"] == "train"], args.seed)
    val = stratified_order([r for r in rows if r["split"] == "val"], args.seed)[: args.val]
    if max(args.sizes) > len(train):
        raise SystemExit(f"{args.manifest}: {len(train)} train clips, fewer than {max(args.sizes)}")
    if len(val) < args.val:
        raise SystemExit(f"{args.manifest}: {len(val)} val clips, fewer than {args.val}")
    args.out.mkdir(parents=True, exist_ok=True)
    for size in sorted(args.sizes):
        with open(args.out / f"train-{size}.csv", "w", newline="") as stream:
            writer = csv.DictWriter(stream, fieldnames=fields)
            writer.writeheader()
            writer.writerows(sorted(train[:size] + val, key=lambda r: r["scenario_id"]))
        counts = defaultdict(int)
        for row in train[:size]:
            counts[row["category"]] += 1
        print(f"train-{size}: " + ", ".join(f"{c} {n}" for c, n in sorted(counts.items())))
    needed = sorted({r["scenario_id"] for r in train[: max(args.sizes)] + val})
    (args.out / "clips.txt").write_text("\n".join(needed) + "\n")
    print(f"{len(needed)} clips needed ({max(args.sizes)} train, {len(val)} val): {args.out}")


if __name__ == "__main__":
    main()
