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
#   WORKERS=auto (collection)  EVAL_WORKERS=<cores / 2>  SYNTH_WORKERS=<cores>
#   SENSOR_HZ=2  MANIFEST=splits/synthetic-800.csv  DRIVEE2E=drivee2e (the command)  PYTHON=python3
#   CPU_THREADS=4  torch's threads in the commands that compute on the CPU beside the others
#                  (AD-MLP's training, open-loop planning and scoring): a pool as wide as a busy
#                  host waits on itself (AD-MLP's 200-clip training over 10 min on 32 threads)
#   RECORD=mp4     the largest size's closed loops (seed 0) also write each episode's MP4 (none: no)
# The host is used whole, as a pipeline: synthesis and collection on every core and GPU; each
# model's features cached once for the largest subset (the smaller ones are inside it) and the
# val clips; then the trainings run in lanes, one lane per GPU taking the next image-model
# training as it frees (the largest size first, so the table's row comes first) and one lane on
# the CPU for AD-MLP, while each checkpoint is scored as soon as it is trained (open loop from
# the cache, then closed loop with EVAL_WORKERS workers; the scorings that overlap share the
# cores and the GPUs). On a host without a GPU the image models train in turn on the CPU.
# Every stage resumes: synthesis and collection skip finished clips, the caches finished clips,
# a finished training is not run again (OUT/checkpoints/NAME.done) and an unfinished one resumes
# from its checkpoint, evaluation from its finished episodes. OUT/times.tsv gets each stage's
# seconds (stages of different lanes overlap; `total` is the wall time; a resumed run appends its
# own after a line naming when it started), and each stage's line is printed as it ends.
set -euo pipefail
OUT="${1:?usage: bash scripts/benchmark.sh OUT}"
HERE="$(cd "$(dirname "$0")" && pwd)"
PYTHON="${PYTHON:-python3}"
DRIVEE2E="${DRIVEE2E:-drivee2e}"
CORES="$(getconf _NPROCESSORS_ONLN 2>/dev/null || echo 2)"
GPUS="$("$PYTHON" -c 'import torch; print(torch.cuda.device_count())' 2>/dev/null || echo 0)"
SIZES="${SIZES:-25 50 100 200}"
VAL="${VAL:-40}"
MODELS="${MODELS:-admlp camera tcp}"
LARGEST="$(echo "$SIZES" | tr ' ' '\n' | sort -n | tail -1)"
SMALLEST="$(echo "$SIZES" | tr ' ' '\n' | sort -n | head -1)"
SPREAD_SIZE="${SPREAD_SIZE:-$LARGEST}"
MANIFEST="${MANIFEST:-$HERE/../splits/synthetic-800.csv}"
DATA="$OUT/data"
IMAGE_MODELS=()
for model in $MODELS; do [ "$model" = admlp ] || IMAGE_MODELS+=("$model"); done
CPU_THREADS="${CPU_THREADS:-4}"
[ "$CPU_THREADS" -le "$CORES" ] || CPU_THREADS="$CORES"
RECORD="${RECORD:-mp4}"
EVAL_WORKERS="${EVAL_WORKERS:-$(( CORES / 2 ))}"  # scorings overlap: two at a time fill the cores
[ "$EVAL_WORKERS" -ge 1 ] || EVAL_WORKERS=1
mkdir -p "$OUT/runs" "$OUT/openloop" "$OUT/checkpoints" "$OUT/logs"
rm -rf "$OUT/claims"  # claims of a run that was cut short: its trainings resume
mkdir -p "$OUT/claims"
echo "# run started $(date -u +%Y-%m-%dT%H:%M:%SZ) on $(hostname), $CORES cores, $GPUS GPUs" \
    >> "$OUT/times.tsv"
RUN_START="$(date +%s)"

stage() {  # stage NAME COMMAND...: run it, record its seconds, return its exit status
    local name="$1" start seconds
    shift
    start="$(date +%s%N)"
    echo "== $name ($(date -u +%H:%M:%S))" >&2
    local status=0
    "$@" || status=$?
    seconds="$(( ($(date +%s%N) - start) / 1000000000 ))"
    [ "$status" -eq 0 ] || name="$name (failed, exit $status)"
    printf '%s\t%d\n' "$name" "$seconds" >> "$OUT/times.tsv"
    echo "== $name: ${seconds} s" >&2
    return "$status"
}

logged() {  # logged LOG COMMAND...: its output into LOG
    local log="$1"
    shift
    "$@" > "$log" 2>&1
}

# shellcheck disable=SC2086
stage subsets "$PYTHON" "$HERE/benchmark_subsets.py" "$MANIFEST" --sizes $SIZES --val "$VAL" \
    --out "$OUT/manifests"
mapfile -t CLIPS < "$OUT/manifests/clips.txt"
stage synth "$DRIVEE2E" synth --out "$DATA" --clips 800 --intersections 15 --seed 0 \
    --workers "${SYNTH_WORKERS:-$CORES}" --only "${CLIPS[@]}"
stage collect "$DRIVEE2E" collect "$DATA" --workers "${WORKERS:-auto}" \
    --sensor-hz "${SENSOR_HZ:-2}" --only "${CLIPS[@]}"

evaluate() {  # evaluate RUN AGENT MANIFEST WORKERS [CHECKPOINT [RECORD]]
    local run="$1" agent="$2" manifest="$3" workers="$4" checkpoint=() record=()
    [ -n "${5:-}" ] && checkpoint=(--checkpoint "$5")
    [ -n "${6:-}" ] && [ "$6" != none ] && record=(--record "$6")
    "$DRIVEE2E" evaluate "$DATA" --split val --split-name "$manifest" --agent "$agent" \
        "${checkpoint[@]}" "${record[@]}" --workers "$workers" --out "$OUT/runs/$run" \
        > "$OUT/logs/eval-$run.log" 2>&1
}

openloop() {  # openloop NAME MODEL MANIFEST [CHECKPOINT]: plans and scores them, one process
    local name="$1" model="$2" manifest="$3" checkpoint=()
    [ -n "${4:-}" ] && checkpoint=(--checkpoint "$4")
    OMP_NUM_THREADS="$CPU_THREADS" "$DRIVEE2E" openloop "$DATA" --split val \
        --split-name "$manifest" --model "$model" "${checkpoint[@]}" \
        --write-predictions "$OUT/openloop/$name.parquet" --convention stp3 uniad \
        --json "$OUT/openloop/${name}_{convention}.json" > "$OUT/logs/openloop-$name.log" 2>&1
}

# The references first: constant velocity's open loop also builds the val clips' scoring cache
# that every later open loop reads (built once, before the evaluators run side by side).
VAL_MANIFEST="$OUT/manifests/train-$SMALLEST.csv"  # every manifest holds the same val clips
for reference in ${REFERENCES-expert constant-velocity}; do
    stage "closedloop $reference" evaluate "$reference" "$reference" "$VAL_MANIFEST" auto
    if [ "$reference" != expert ]; then  # the expert reads the logged future: no open loop
        stage "openloop $reference" openloop "$reference" "$reference" "$VAL_MANIFEST"
    fi
done

for model in $MODELS; do  # each model's features once: the largest subset holds the others
    stage "cache $model" logged "$OUT/logs/cache-$model.log" "$DRIVEE2E" cache "$DATA" \
        --model "$model" --split train --split-name "$OUT/manifests/train-$LARGEST.csv"
    stage "cache $model val" logged "$OUT/logs/cache-$model-val.log" "$DRIVEE2E" cache "$DATA" \
        --model "$model" --split val --split-name "$VAL_MANIFEST"
done

epochs_of() {
    case "$1" in
        admlp) echo "${EPOCHS_ADMLP:-60}";;
        camera) echo "${EPOCHS_CAMERA:-40}";;
        tcp) echo "${EPOCHS_TCP:-30}";;
    esac
}

# The trainings, "model size seed" a line: the largest size first, then the others, then the
# second seed of the image models.
ORDERED_SIZES="$LARGEST"
for size in $(echo "$SIZES" | tr ' ' '\n' | sort -n); do
    [ "$size" = "$LARGEST" ] || ORDERED_SIZES="$ORDERED_SIZES $size"
done
JOBS=()
for size in $ORDERED_SIZES; do
    for model in $MODELS; do JOBS+=("$model $size 0"); done
done
if [ "$SPREAD_SIZE" != none ]; then
    for model in "${IMAGE_MODELS[@]}"; do JOBS+=("$model $SPREAD_SIZE 1"); done
fi

train() {  # train MODEL SIZE SEED DEVICE: marks NAME.done or NAME.failed
    local model="$1" size="$2" seed="$3" device="$4" name="$1-$2-seed$3"
    [ -e "$OUT/checkpoints/$name.done" ] && return 0
    rm -f "$OUT/checkpoints/$name.failed"
    local threads=()
    [ "$device" = cpu ] && threads=(env OMP_NUM_THREADS="$CPU_THREADS")
    if stage "train $name ($device)" logged "$OUT/logs/train-$name.log" "${threads[@]}" \
        "$DRIVEE2E" train "$model" "$DATA" --split train \
        --split-name "$OUT/manifests/train-$size.csv" --epochs "$(epochs_of "$model")" \
        --seed "$seed" --device "$device" --out "$OUT/checkpoints/$name.pt"; then
        touch "$OUT/checkpoints/$name.done"
    else
        echo "== train $name failed: $OUT/logs/train-$name.log" >&2
        touch "$OUT/checkpoints/$name.failed"
    fi
}

lane() {  # lane DEVICE MODEL...: claim the next unclaimed training of these models, run it
    local device="$1" job model size seed
    shift
    for job in "${JOBS[@]}"; do
        read -r model size seed <<< "$job"
        [[ " $* " == *" $model "* ]] || continue
        mkdir "$OUT/claims/$model-$size-seed$seed" 2> /dev/null || continue  # atomic claim
        train "$model" "$size" "$seed" "$device"
    done
}

evaluator() {  # evaluator MODEL SIZE SEED: score that training once it is finished
    local model="$1" size="$2" seed="$3" name="$1-$2-seed$3" workers="$EVAL_WORKERS"
    [ "$model" = admlp ] && workers=auto  # draws nothing: a few workers suffice
    until [ -e "$OUT/checkpoints/$name.done" ] || [ -e "$OUT/checkpoints/$name.failed" ]; do
        sleep 2
    done
    [ -e "$OUT/checkpoints/$name.done" ] || return 0
    local manifest="$OUT/manifests/train-$size.csv" weights="$OUT/checkpoints/$name.pt"
    stage "openloop $name" openloop "$name" "$model" "$manifest" "$weights" ||
        echo "== openloop $name failed" >&2
    local kind=none
    [ "$size" = "$LARGEST" ] && [ "$seed" = 0 ] && kind="$RECORD"
    stage "closedloop $name" evaluate "$name" "$model" "$manifest" "$workers" "$weights" \
        "$kind" ||
        echo "== closedloop $name failed: $OUT/logs/eval-$name.log" >&2
}

pids=()
for job in "${JOBS[@]}"; do  # an evaluator per training, each waiting for its checkpoint
    # shellcheck disable=SC2086
    evaluator $job &
    pids+=($!)
done
if [[ " $MODELS " == *" admlp "* ]]; then  # AD-MLP reads no image: it trains on the CPU
    lane cpu admlp &
    pids+=($!)
fi
if [ "${#IMAGE_MODELS[@]}" -gt 0 ]; then
    if [ "$GPUS" -gt 0 ]; then
        for (( gpu = 0; gpu < GPUS; gpu++ )); do
            lane "cuda:$gpu" "${IMAGE_MODELS[@]}" &
            pids+=($!)
        done
    else
        lane cpu "${IMAGE_MODELS[@]}" &
        pids+=($!)
    fi
fi
status=0
for pid in "${pids[@]}"; do wait "$pid" || status=1; done
printf 'total\t%d\n' "$(( $(date +%s) - RUN_START ))" >> "$OUT/times.tsv"
"$PYTHON" "$HERE/benchmark_report.py" "$OUT"
ls "$OUT"/checkpoints/*.failed > /dev/null 2>&1 && { echo "some trainings failed" >&2; status=1; }
exit "$status"
