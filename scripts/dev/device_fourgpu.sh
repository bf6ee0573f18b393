#!/usr/bin/env bash
# The learning side's multi-GPU figures on a fresh GPU host, in one device call (issues 59 and
# 60): its environment (scripts/gpu_env.sh), CLIPS synthetic clips (seed 0) collected at 2 Hz,
# TCP's feature cache, then
#   1. TCP trained alone on cuda:0 (EPOCHS epochs, seed 0), then one training per GPU side by
#      side (seeds 1..GPUS): each one's wall time against the one alone;
#   2. closed loop through the CLI (`evaluate --split all --workers auto`) with TCP (the
#      checkpoint of step 1), AD-MLP (trained briefly on the CPU) and constant velocity, the
#      GPUs' utilisation sampled each second, and the breakdown of a scene's time per run.
# With BASE_TAR (carried: `git archive REV $(git diff --name-only REV -- drivee2e_data loaders
# collect) -o out/base_overlay.tar`, the files that differ), each closed loop runs with that
# version first, then this one (both through `python3 -m drivee2e_data.cli`).
# Every step's output goes to $OUT/log.txt as it runs; a step that fails is reported and the
# others still run.
#   CLIPS=40 EPOCHS=30 [BASE_TAR=out/base_overlay.tar] bash scripts/dev/device_fourgpu.sh
set -uo pipefail
repo=$(pwd)
CLIPS="${CLIPS:-40}"
EPOCHS="${EPOCHS:-30}"
DATA=/tmp/fourgpu
LOG="${OUT:-/tmp}/log.txt"
say() { echo "$*" | tee -a "$LOG"; }
start=$(date +%s)
# shellcheck source=scripts/dev/device_env.sh
source "$repo/scripts/dev/device_env.sh"  # the environment; `versions`
gpus=$(nvidia-smi -L | wc -l)
say "environment: $(( $(date +%s) - start )) s; $(nproc) cores; $gpus GPUs"
cd /tmp || exit 1
step() {  # step NAME COMMAND...: run it (output to /tmp/logs/NAME.log), print its seconds
    local name="$1" t status=0
    shift
    mkdir -p /tmp/logs
    t=$(date +%s.%N)
    "$@" > "/tmp/logs/$name.log" 2>&1 || status=$?
    say "$name: $(python3 -c "print(f'{$(date +%s.%N) - $t:.1f}')") s$( [ $status = 0 ] || echo " FAILED (exit $status)")"
    [ $status = 0 ] || tail -5 "/tmp/logs/$name.log" | tee -a "$LOG"
    return $status
}
step synth drivee2e synth --out "$DATA" --clips "$CLIPS" --seed 0 --workers "$(nproc)" &&
step curate drivee2e curate "$DATA" &&
step collect drivee2e collect "$DATA" --workers auto --sensor-hz 2 &&
step split drivee2e split "$DATA" --seed 0 &&
step cache-tcp drivee2e cache "$DATA" --model tcp --split all || exit 1

# 1. trainings: alone, then one per GPU side by side
step train-alone drivee2e train tcp "$DATA" --split all --epochs "$EPOCHS" --seed 0 \
    --device cuda:0 --out "$DATA/tcp.pt"
nvidia-smi --query-gpu=timestamp,index,utilization.gpu --format=csv,noheader,nounits -l 1 \
    > /tmp/util-trainings.csv 2>/dev/null &
logger=$!
pids=()
for (( g = 0; g < gpus; g++ )); do
    step "train-side-by-side-cuda$g" drivee2e train tcp "$DATA" --split all --epochs "$EPOCHS" \
        --seed $(( g + 1 )) --device "cuda:$g" --out "$DATA/tcp-$g.pt" &
    pids+=($!)
done
for pid in "${pids[@]}"; do wait "$pid"; done
kill "$logger"
say "GPU busy % while side by side (mean of 1 s samples per GPU): $(awk -F', ' \
    '{s[$2]+=$3; n[$2]++} END {for (g in s) printf "%s:%.0f ", g, s[g]/n[g]}' \
    /tmp/util-trainings.csv)"
grep -H "epochs in" /tmp/logs/train-*.log | sed "s|.*/train-||" | cut -c1-200 | tee -a "$LOG"

# 2. closed loop, every agent kind
OMP_NUM_THREADS=4 step train-admlp drivee2e train admlp "$DATA" --split all --epochs 10 \
    --device cpu --out "$DATA/admlp.pt"
runs=()
for agent in tcp admlp constant-velocity; do
    checkpoint=()
    [ "$agent" = constant-velocity ] || checkpoint=(--checkpoint "$DATA/$agent.pt")
    for version in "${versions[@]}"; do
        run="$DATA/runs/$agent-$version"
        path=/tmp/proj
        [ "$version" = base ] && path=/tmp/proj_base
        rm -rf "$run"
        nvidia-smi --query-gpu=utilization.gpu --format=csv,noheader,nounits -l 1 \
            > "/tmp/util-$agent-$version" 2>/dev/null &
        logger=$!
        began=$(date +%s.%N)
        step "evaluate-$agent-$version" env PYTHONPATH="$path:/tmp/site" python3 -m \
            drivee2e_data.cli evaluate "$DATA" --split all --agent "$agent" "${checkpoint[@]}" \
            --workers auto --out "$run" && runs+=("$run")
        date +%s.%N > "$run/command_ended"
        echo "$began" > "$run/command_started"
        kill "$logger"
        say "  GPU busy % (mean of 1 s samples over all GPUs): $(awk '{s+=$1; n++} END \
            {printf "%.0f", s/n}' "/tmp/util-$agent-$version")"
    done
done
python3 "$repo/scripts/dev/closedloop_breakdown.py" "${runs[@]}" 2>&1 | tee -a "$LOG"
if [ -n "${OUT:-}" ]; then  # one archive: a device call brings back only a few files
    tar -czf "$OUT/fourgpu.tar.gz" -C / tmp/logs $(cd / && ls -d tmp/util-* 2>/dev/null) \
        $(cd / && ls -d tmp/fourgpu/runs/*/{episodes.parquet,summary.json,command_*} 2>/dev/null)
fi
say "total: $(( $(date +%s) - start )) s"
