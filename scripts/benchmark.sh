#!/usr/bin/env bash
# Benchmark v1: every baseline trained on nested, behaviour-stratified subsets of the canonical
# 800-clip set's train split and scored open loop (L2, collisions) and closed loop (SR, DS) on
# the same val clips; then the tables and the scaling figure (scripts/benchmark_report.py).
#   bash scripts/benchmark.sh OUT
# Settings (environment):
#   SIZES="25 50 100 200"  training subsets (clips; nested)      VAL=40  val clips scored
#   SPREAD_SIZE=<largest>  the size trained with a second seed (run-to-run spread; none: no)
#   MODELS="admlp camera tcp"  the trained baselines   REFERENCES="expert constant-velocity"
#   EPOCHS_ADMLP=60 EPOCHS_CAMERA=40 EPOCHS_TCP=30  DEVICE=auto (tcp: cuda where there is one)
#   WORKERS=auto (collection)  EVAL_WORKERS=<cores>  SYNTH_WORKERS=<cores>  SENSOR_HZ=2
#   MANIFEST=splits/synthetic-800.csv  DRIVEE2E=drivee2e (the command)  PYTHON=python3
# Every stage resumes: synthesis and collection skip finished clips, training resumes from its
# checkpoint, evaluation from its finished episodes; OUT/times.tsv gets each stage's seconds
# (a resumed run appends its own, after a line naming when it started).
set -euo pipefail
OUT="${1:?usage: bash scripts/benchmark.sh OUT}"
HERE="$(cd "$(dirname "$0")" && pwd)"
CORES="$(getconf _NPROCESSORS_ONLN 2>/dev/null || echo 2)"
SIZES="${SIZES:-25 50 100 200}"
VAL="${VAL:-40}"
LARGEST="$(echo "$SIZES" | tr ' ' '\n' | sort -n | tail -1)"
SMALLEST="$(echo "$SIZES" | tr ' ' '\n' | sort -n | head -1)"
SPREAD_SIZE="${SPREAD_SIZE:-$LARGEST}"
EVAL_WORKERS="${EVAL_WORKERS:-$CORES}"
DEVICE="${DEVICE:-auto}"
MANIFEST="${MANIFEST:-$HERE/../splits/synthetic-800.csv}"
DRIVEE2E="${DRIVEE2E:-drivee2e}"
PYTHON="${PYTHON:-python3}"
DATA="$OUT/data"
mkdir -p "$OUT/runs" "$OUT/openloop" "$OUT/checkpoints"
echo "# run started $(date -u +%Y-%m-%dT%H:%M:%SZ) on $(hostname), $CORES cores" >> "$OUT/times.tsv"

stage() {  # stage NAME COMMAND...: run it, record its seconds
    local name="$1" start
    shift
    start="$(date +%s%N)"
    echo "== $name" >&2
    "$@"
    printf '%s\t%d\n' "$name" "$(( ($(date +%s%N) - start) / 1000000000 ))" >> "$OUT/times.tsv"
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

train() {  # train MODEL SIZE SEED
    local model="$1" size="$2" seed="$3" epochs
    case "$model" in
        admlp) epochs="${EPOCHS_ADMLP:-60}";;
        camera) epochs="${EPOCHS_CAMERA:-40}";;
        tcp) epochs="${EPOCHS_TCP:-30}";;
    esac
    local name="$model-$size-seed$seed" manifest="$OUT/manifests/train-$size.csv"
    local checkpoint="$OUT/checkpoints/$name.pt" device=()
    [ "$model" = tcp ] && device=(--device "$DEVICE")
    stage "train $name" "$DRIVEE2E" train "$model" "$DATA" --split train --split-name "$manifest" \
        --epochs "$epochs" --seed "$seed" "${device[@]}" --out "$checkpoint" > /dev/null
    stage "openloop $name" openloop "$name" "$model" "$manifest" "$checkpoint"
    stage "closedloop $name" evaluate "$name" "$model" "$manifest" "$checkpoint"
}

for size in $SIZES; do
    for model in ${MODELS:-admlp camera tcp}; do
        train "$model" "$size" 0
    done
done
if [ "$SPREAD_SIZE" != none ]; then
    for model in ${MODELS:-admlp camera tcp}; do
        [ "$model" = admlp ] && continue  # the image models' spread
        train "$model" "$SPREAD_SIZE" 1
    done
fi
"$PYTHON" "$HERE/benchmark_report.py" "$OUT"
