#!/usr/bin/env bash
# Benchmark v1: every baseline trained on nested, behaviour-stratified subsets of the canonical
# 800-clip set's train split and scored open loop (L2, collisions) and closed loop (SR, DS) on
# the same val clips; then the tables and the scaling figure (scripts/benchmark_report.py).
#   bash scripts/benchmark.sh OUT
# Settings (environment):
#   SIZES="25 50 100 200"  training subsets (clips; nested)      VAL=40  val clips scored
#   SPREAD_SIZE=<largest>  the size trained with a second seed (run-to-run spread; none: no)
#   MODELS="admlp camera tcp"  the trained baselines   REFERENCES="expert constant-velocity"
#   EPOCHS_ADMLP=60 EPOCHS_CAMERA=40 EPOCHS_TCP=30
#   WORKERS=auto (collection)  EVAL_WORKERS=auto  SYNTH_WORKERS=<cores>  SENSOR_HZ=2
#   MANIFEST=splits/synthetic-800.csv  DRIVEE2E=drivee2e (the command)  PYTHON=python3
# The host is used whole: synthesis and collection on every core and GPU; each size's features
# cached once per model (drivee2e cache, every core); the models of one size trained side by
# side, one per GPU (cuda:N round robin; on a host without one, one after another); the closed
# loop with --workers auto (a worker per core, renderers and policy servers on every GPU).
# Every stage resumes: synthesis and collection skip finished clips, the caches finished clips,
# training resumes from its checkpoint, evaluation from its finished episodes; OUT/times.tsv
# gets each stage's seconds (a resumed run appends its own, after a line naming when it
# started), and each stage's line is printed as it ends.
set -euo pipefail
OUT="${1:?usage: bash scripts/benchmark.sh OUT}"
HERE="$(cd "$(dirname "$0")" && pwd)"
CORES="$(getconf _NPROCESSORS_ONLN 2>/dev/null || echo 2)"
SIZES="${SIZES:-25 50 100 200}"
VAL="${VAL:-40}"
LARGEST="$(echo "$SIZES" | tr ' ' '\n' | sort -n | tail -1)"
SMALLEST="$(echo "$SIZES" | tr ' ' '\n' | sort -n | head -1)"
SPREAD_SIZE="${SPREAD_SIZE:-$LARGEST}"
EVAL_WORKERS="${EVAL_WORKERS:-auto}"
GPUS="$("$PYTHON" -c 'import torch; print(torch.cuda.device_count())' 2>/dev/null || echo 0)"
MANIFEST="${MANIFEST:-$HERE/../splits/synthetic-800.csv}"
DRIVEE2E="${DRIVEE2E:-drivee2e}"
PYTHON="${PYTHON:-python3}"
DATA="$OUT/data"
mkdir -p "$OUT/runs" "$OUT/openloop" "$OUT/checkpoints"
echo "# run started $(date -u +%Y-%m-%dT%H:%M:%SZ) on $(hostname), $CORES cores" >> "$OUT/times.tsv"

stage() {  # stage NAME COMMAND...: run it, record its seconds
    local name="$1" start seconds
    shift
    start="$(date +%s%N)"
    echo "== $name ($(date -u +%H:%M:%S))" >&2
    "$@"
    seconds="$(( ($(date +%s%N) - start) / 1000000000 ))"
    printf '%s\t%d\n' "$name" "$seconds" >> "$OUT/times.tsv"
    echo "== $name: ${seconds} s" >&2
}

# shellcheck disable=SC2086
stage subsets "$PYTHON" "$HERE/benchmark_subsets.py" "$MANIFEST" --sizes $SIZES --val "$VAL" \
    --out "$OUT/manifests"
mapfile -t CLIPS < "$OUT/manifests/clips.txt"
stage synth "$DRIVEE2E" synth --out "$DATA" --clips 800 --intersections 15 --seed 0 \
    --workers "${SYNTH_WORKERS:-$CORES}" --only "${CLIPS[@]}"
stage collect "$DRIVEE2E" collect "$DATA" --workers "${WORKERS:-auto}" \
    --sensor-hz "${SENSOR_HZ:-2}" --only "${CLIPS[@]}"

evaluate() {  # evaluate RUN AGENT MANIFEST [CHECKPOINT]
    local run="$1" agent="$2" manifest="$3" checkpoint=()
    [ -n "${4:-}" ] && checkpoint=(--checkpoint "$4")
    "$DRIVEE2E" evaluate "$DATA" --split val --split-name "$manifest" --agent "$agent" \
        "${checkpoint[@]}" --workers "$EVAL_WORKERS" --out "$OUT/runs/$run" > /dev/null
}

openloop() {  # openloop NAME MODEL MANIFEST [CHECKPOINT]
    local name="$1" model="$2" manifest="$3" checkpoint=()
    [ -n "${4:-}" ] && checkpoint=(--checkpoint "$4")
    "$DRIVEE2E" predict "$DATA" --split val --split-name "$manifest" --model "$model" \
        "${checkpoint[@]}" --out "$OUT/openloop/$name.parquet" > /dev/null
    for convention in stp3 uniad; do
        "$DRIVEE2E" openloop "$DATA" --split val --split-name "$manifest" \
            --predictions "$OUT/openloop/$name.parquet" --convention "$convention" \
            --json "$OUT/openloop/${name}_$convention.json" > /dev/null
    done
}

VAL_MANIFEST="$OUT/manifests/train-$SMALLEST.csv"  # every manifest holds the same val clips
for reference in ${REFERENCES-expert constant-velocity}; do
    stage "closedloop $reference" evaluate "$reference" "$reference" "$VAL_MANIFEST"
    if [ "$reference" != expert ]; then  # the expert reads the logged future: no open loop
        stage "openloop $reference" openloop "$reference" "$reference" "$VAL_MANIFEST"
    fi
done

epochs_of() {
    case "$1" in
        admlp) echo "${EPOCHS_ADMLP:-60}";;
        camera) echo "${EPOCHS_CAMERA:-40}";;
        tcp) echo "${EPOCHS_TCP:-30}";;
    esac
}

train() {  # train MODEL SIZE SEED DEVICE
    local model="$1" size="$2" seed="$3" device="$4"
    local name="$model-$size-seed$seed" manifest="$OUT/manifests/train-$size.csv"
    stage "train $name" "$DRIVEE2E" train "$model" "$DATA" --split train --split-name "$manifest" \
        --epochs "$(epochs_of "$model")" --seed "$seed" --device "$device" \
        --out "$OUT/checkpoints/$name.pt" > /dev/null
}

train_side_by_side() {  # SIZE SEED MODEL...: one training per GPU at a time, then their scores
    local size="$1" seed="$2" k=0 pids=() model device
    shift 2
    for model in "$@"; do  # each model's features once, on every core, before the trainings
        stage "cache $model-$size" "$DRIVEE2E" cache "$DATA" --model "$model" --split train \
            --split-name "$OUT/manifests/train-$size.csv" > /dev/null
    done
    for model in "$@"; do
        device=cpu
        if [ "$GPUS" -gt 0 ] && [ "$model" != admlp ]; then device="cuda:$(( k % GPUS ))"; k=$((k + 1)); fi
        if [ "$GPUS" -gt 1 ]; then
            train "$model" "$size" "$seed" "$device" &
            pids+=($!)
        else
            train "$model" "$size" "$seed" "$device"
        fi
    done
    for pid in "${pids[@]}"; do wait "$pid"; done
    for model in "$@"; do
        local name="$model-$size-seed$seed" manifest="$OUT/manifests/train-$size.csv"
        stage "openloop $name" openloop "$name" "$model" "$manifest" "$OUT/checkpoints/$name.pt"
        stage "closedloop $name" evaluate "$name" "$model" "$manifest" "$OUT/checkpoints/$name.pt"
    done
}

for size in $SIZES; do
    # shellcheck disable=SC2086
    train_side_by_side "$size" 0 ${MODELS:-admlp camera tcp}
done
if [ "$SPREAD_SIZE" != none ]; then
    spread=()
    for model in ${MODELS:-admlp camera tcp}; do
        [ "$model" = admlp ] || spread+=("$model")  # the image models' spread
    done
    [ "${#spread[@]}" -gt 0 ] && train_side_by_side "$SPREAD_SIZE" 1 "${spread[@]}"
fi
"$PYTHON" "$HERE/benchmark_report.py" "$OUT"
