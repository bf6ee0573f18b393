#!/usr/bin/env bash
# Open-loop baselines on a collected, split data root: trains AD-MLP on the train split, plans
# with it and with constant velocity on SPLIT, and scores both in both L2 conventions.
#   bash scripts/openloop_baselines.sh DATA [SPLIT (default val)] [EPOCHS (default 60)]
# Writes DATA/results/openloop/{admlp.pt, <model>_<split>.parquet, <model>_<split>_<convention>.json}
# and prints the tables. Rerunning resumes the training and rewrites the rest.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA="$1"
SPLIT="${2:-val}"
EPOCHS="${3:-60}"
OUT="$DATA/results/openloop"
DRIVEE2E="${DRIVEE2E:-.venv/bin/drivee2e}"
mkdir -p "$OUT"
[ -f "$DATA/splits/default.csv" ] || "$DRIVEE2E" split "$DATA"
"$DRIVEE2E" train admlp "$DATA" --split train --epochs "$EPOCHS" --out "$OUT/admlp.pt"
for model in constant-velocity admlp; do  # plans made and scored in one process each
    echo "== $model on $SPLIT (stp3, uniad)"
    CHECKPOINT=()
    [ "$model" = admlp ] && CHECKPOINT=(--checkpoint "$OUT/admlp.pt")
    "$DRIVEE2E" openloop "$DATA" --split "$SPLIT" --model "$model" "${CHECKPOINT[@]}" \
        --write-predictions "$OUT/${model}_$SPLIT.parquet" \
        --convention stp3 uniad --json "$OUT/${model}_${SPLIT}_{convention}.json"
done
