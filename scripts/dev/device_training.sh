#!/usr/bin/env bash
# Issue 59's one-GPU figures at Benchmark v1's scale, on a fresh GPU host, in the background
# (setsid) so the run goes on between device calls: TRAIN training clips and VAL val clips of
# the canonical manifest (scripts/benchmark_subsets.py, seed 0) synthesised and collected whole
# at 2 Hz; the tests that need a GPU (pytest from .whl); each model's feature caches; TCP
# trained EPOCHS epochs on cuda:0 with the GPU's utilisation logged each second; short trainings
# (SHORT_EPOCHS) on the same cache, one after the other: with BASE_TAR that version and this
# one, and this one without CUDA graphs (--no-cuda-graphs); AD-MLP trained on the CPU;
# open loop (predict, then both conventions scored; then both in one process, `openloop
# --model`) of constant velocity (twice: the first run builds the val clips' scoring cache),
# AD-MLP and TCP; the training step's probe
# (scripts/dev/bench_training_step.py, with STEP_PROBE=1); TCP's closed loop twice on CLOSEDLOOP
# val clips (0: not), to see whether GPU runs repeat to the bit. Each step's seconds go to
# /tmp/training/log.txt as it ends.
#   [BASE_TAR=out/base_overlay.tar] bash scripts/dev/device_training.sh && \
#       bash scripts/dev/device_training.sh --wait 500   # the first call: start, then wait
#   bash scripts/dev/device_training.sh --wait 540       # each later call, made at once
# Carry .gl, .whl and .pb (and the BASE_TAR file). A machine stays warm only 30 s after a call.
set -uo pipefail
RUN=/tmp/training
LOG="$RUN/log.txt"
if [ "${1:-}" = --wait ]; then
    # shellcheck source=scripts/dev/device_wait.sh
    source "$(dirname "$0")/device_wait.sh"
    wait_for "^total:" "$LOG" "${2:-540}"
    cat "$LOG"
    if [ -n "${OUT:-}" ]; then
        cp "$LOG" "$OUT/log.txt"
        tar -czf "$OUT/training.tar.gz" -C "$RUN" logs util.csv openloop \
            $(cd "$RUN" && ls -d runs/*/summary.json runs/*/episodes.parquet 2>/dev/null)
    fi
    exit 0
fi
repo="$RUN/repo"  # the scripts and manifests the run reads, copied out of the checkout
TRAIN="${TRAIN:-400}"
VAL="${VAL:-100}"
EPOCHS="${EPOCHS:-30}"
SHORT_EPOCHS="${SHORT_EPOCHS:-3}"
say() { echo "$*" >> "$LOG"; }
if [ "${1:-}" != --run ]; then  # set the host up, then the run in a session of its own
    rm -rf "$RUN" && mkdir -p "$RUN/logs" "$RUN/openloop" "$repo"
    cp -r scripts splits tests pyproject.toml "$repo/"
    start=$(date +%s)
    # shellcheck source=scripts/dev/device_env.sh
    source scripts/dev/device_env.sh  # the environment; a base version in /tmp/proj_base
    say "environment: $(( $(date +%s) - start )) s; $(nproc) cores; $(nvidia-smi -L | wc -l) GPUs"
    TZ=UTC setsid nvidia-smi --query-gpu=timestamp,index,utilization.gpu,memory.used \
        --format=csv,noheader,nounits -l 1 > "$RUN/util.csv" 2>/dev/null &
    echo "$start" > "$RUN/started"
    setsid bash "$repo/scripts/dev/device_training.sh" --run > "$RUN/run.log" 2>&1 < /dev/null &
    echo "started; log: $LOG"
    exit 0
fi
# shellcheck disable=SC1091
source /tmp/drivee2e_env
export PATH="/tmp/proj/bin:$PATH"
versions=(work)
[ -n "${BASE_TAR:-}" ] && versions=(base work)
start=$(cat "$RUN/started")

step() {  # step NAME COMMAND...: run it (output to logs/NAME.log), log its seconds and span
    local name="$1" t status=0
    shift
    t=$(date +%s.%N)
    "$@" > "$RUN/logs/$name.log" 2>&1 || status=$?
    echo "$t $(date +%s.%N)" > "$RUN/logs/$name.span"
    say "$name: $(python3 -c "print(f'{$(date +%s.%N) - $t:.1f}')") s (ended $(date -u \
        +%H:%M:%S))$( [ $status = 0 ] || echo " FAILED (exit $status)")"
    [ $status = 0 ] || tail -5 "$RUN/logs/$name.log" >> "$LOG"
    return $status
}
busy() {  # busy NAME: the GPUs' utilisation over that step's span
    say "  GPU busy during $1: $(python3 "$repo/scripts/dev/gpu_busy.py" "$RUN/util.csv" \
        $(cat "$RUN/logs/$1.span"))"
}

run() {
    local DATA="$RUN/data" manifests="$RUN/manifests"
    cd /tmp || exit 1
    step subsets python3 "$repo/scripts/benchmark_subsets.py" "$repo/splits/synthetic-800.csv" \
        --sizes "$TRAIN" --val "$VAL" --out "$manifests" || return 1
    local manifest="$manifests/train-$TRAIN.csv"
    # the tests that need a GPU (TCP's CUDA graphs against its eager training), first
    if [ "${GPU_TESTS:-1}" = 1 ]; then
        (cd "$repo" && step gpu-tests python3 -m pytest -q -p no:cacheprovider -k cuda \
            tests/test_tcp.py)
        say "  $(tail -1 "$RUN/logs/gpu-tests.log")"
    fi
    mapfile -t clips < "$manifests/clips.txt"
    step synth drivee2e synth --out "$DATA" --clips 800 --intersections 15 --seed 0 \
        --workers "$(nproc)" --only "${clips[@]}" &&
    step collect drivee2e collect "$DATA" --workers auto --sensor-hz 2 --only "${clips[@]}" ||
        return 1
    for model in admlp tcp; do
        for split in train val; do
            step "cache-$model-$split" drivee2e cache "$DATA" --model "$model" --split "$split" \
                --split-name "$manifest"
        done
    done
    step train-tcp drivee2e train tcp "$DATA" --split train --split-name "$manifest" \
        --epochs "$EPOCHS" --seed 0 --device cuda:0 --out "$RUN/tcp.pt"
    say "  $(grep -h "epochs in" "$RUN/logs/train-tcp.log" | tail -1)"
    busy train-tcp
    # a short training of each version on the same cache, and this one without CUDA graphs
    [ "$SHORT_EPOCHS" -gt 0 ] || versions=()
    for version in ${versions[@]+"${versions[@]}"} $([ "$SHORT_EPOCHS" -gt 0 ] && echo eager); do
        local path=/tmp/proj flags=()
        [ "$version" = base ] && path=/tmp/proj_base
        [ "$version" = eager ] && flags=(--no-cuda-graphs)
        step "train-tcp-short-$version" env PYTHONPATH="$path:/tmp/site" python3 -m \
            drivee2e_data.cli train tcp "$DATA" --split train --split-name "$manifest" \
            --epochs "$SHORT_EPOCHS" --seed 0 --device cuda:0 --out "$RUN/tcp-short-$version.pt" \
            "${flags[@]}"
        say "  $(grep -h "epochs in" "$RUN/logs/train-tcp-short-$version.log" | tail -1)"
        busy "train-tcp-short-$version"
    done
    OMP_NUM_THREADS=4 step train-admlp drivee2e train admlp "$DATA" --split train \
        --split-name "$manifest" --epochs 60 --seed 0 --device cpu --out "$RUN/admlp.pt"
    for name in constant-velocity constant-velocity-again admlp tcp; do
        local model="${name%-again}" checkpoint=()
        [ "$model" = constant-velocity ] || checkpoint=(--checkpoint "$RUN/$model.pt")
        step "predict-$name" drivee2e predict "$DATA" --split val --split-name "$manifest" \
            --model "$model" "${checkpoint[@]}" --out "$RUN/openloop/$name.parquet" &&
        step "openloop-$name" drivee2e openloop "$DATA" --split val --split-name "$manifest" \
            --predictions "$RUN/openloop/$name.parquet" --convention stp3 uniad \
            --json "$RUN/openloop/${name}_{convention}.json"
        # the same in one process (`openloop --model`): the same tables, one start
        step "openloop-one-$name" drivee2e openloop "$DATA" --split val --split-name \
            "$manifest" --model "$model" "${checkpoint[@]}" --convention stp3 uniad \
            --json "$RUN/openloop/${name}_one_{convention}.json" &&
        for convention in stp3 uniad; do
            if cmp -s "$RUN/openloop/${name}_${convention}.json" \
                "$RUN/openloop/${name}_one_${convention}.json"; then
                say "  the same $convention table as predict, then openloop"
            else
                say "  $convention: a table unlike predict's, then openloop's"
            fi
        done
    done
    # what bounds the training step (the feed, the step, the trunk compiled): STEP_PROBE=1
    if [ "${STEP_PROBE:-0}" = 1 ]; then
        step step-probe python3 "$repo/scripts/dev/bench_training_step.py" "$DATA" \
            --split-name "$manifest" --compile default reduce-overhead
        grep -h "samples/s" "$RUN/logs/step-probe.log" | sed 's/^/  /' >> "$LOG"
    fi
    # closed loop of TCP twice on CLOSEDLOOP val clips: the same episodes to the bit? (the
    # policy server's fixed-size batches, issue 60)
    if [ "${CLOSEDLOOP:-40}" -gt 0 ]; then
        python3 - "$manifest" "${CLOSEDLOOP:-40}" "$RUN/closedloop.csv" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
val = [r for r in rows if r["split"] == "val"][: int(sys.argv[2])]
with open(sys.argv[3], "w", newline="") as out:
    writer = csv.DictWriter(out, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(val)
PY
        for run in first second; do
            step "closedloop-tcp-$run" drivee2e evaluate "$DATA" --split val \
                --split-name "$RUN/closedloop.csv" --agent tcp --checkpoint "$RUN/tcp.pt" \
                --workers auto --out "$RUN/runs/tcp-$run"
            say "  $(grep -h "DS" "$RUN/logs/closedloop-tcp-$run.log" | tail -2 | tr '\n' ' ')"
        done
        if cmp -s "$RUN/runs/tcp-first/summary.json" "$RUN/runs/tcp-second/summary.json"; then
            say "  closed loop repeated: the same summary.json"
        else
            say "  closed loop differs between the two runs: $(diff <(python3 -m json.tool \
                "$RUN/runs/tcp-first/summary.json") <(python3 -m json.tool \
                "$RUN/runs/tcp-second/summary.json") | head -6 | tr '\n' ' ')"
        fi
    fi
    say "total: $(( $(date +%s) - start )) s"
}
run
