#!/usr/bin/env bash
# Closed-loop baselines on a curated, collected, split data root: the log-replay expert,
# constant velocity, AD-MLP and the camera policy (both trained on the train split), each
# driven on SPLIT in closed loop; the camera policy is also scored open loop. Then the paper's
# Table 3 shape and the per-behaviour SR table (scripts/results_table.py --closedloop).
#   bash scripts/closedloop_baselines.sh DATA [SPLIT (default val)] [CAMERA_EPOCHS (default 40)]
#   WORKERS=N  evaluation processes (default 2);  EXTRA="--reactive" or "--variant occ-all" ...
# AD-MLP's checkpoint is the open-loop one (scripts/openloop_baselines.sh trains it when absent).
set -euo pipefail
cd "$(dirname "$0")/.."
DATA="$1"
SPLIT="${2:-val}"
EPOCHS="${3:-40}"
WORKERS="${WORKERS:-2}"
EXTRA=(${EXTRA:-})
OUT="$DATA/results/openloop"
DRIVEE2E="${DRIVEE2E:-.venv/bin/drivee2e}"
[ -f "$OUT/admlp_${SPLIT}_stp3.json" ] || bash scripts/openloop_baselines.sh "$DATA" "$SPLIT"
"$DRIVEE2E" train camera "$DATA" --split train --epochs "$EPOCHS" --out "$OUT/camera.pt"
"$DRIVEE2E" openloop "$DATA" --split "$SPLIT" --model camera --checkpoint "$OUT/camera.pt" \
    --write-predictions "$OUT/camera_$SPLIT.parquet" \
    --convention stp3 uniad --json "$OUT/camera_${SPLIT}_{convention}.json" > /dev/null
for agent in expert constant-velocity admlp camera; do
    CHECKPOINT=()
    case "$agent" in admlp|camera) CHECKPOINT=(--checkpoint "$OUT/$agent.pt");; esac
    echo "== $agent on $SPLIT (closed loop) ${EXTRA[*]}"
    "$DRIVEE2E" evaluate "$DATA" --split "$SPLIT" --agent "$agent" "${CHECKPOINT[@]}" \
        --workers "$WORKERS" "${EXTRA[@]}" > /dev/null
done
python3 scripts/results_table.py "$DATA" --split "$SPLIT" --closedloop ${EXTRA_TABLE:-}
