#!/usr/bin/env bash
# Closed-loop speed on a fresh GPU host (issue 60's measurement), in one device call: its
# environment (scripts/gpu_env.sh), CLIPS synthetic clips (seed 0) collected at 2 Hz, TCP and
# the camera policy trained briefly on them (a checkpoint to drive: the network's cost does not
# depend on how well it is trained), then each agent evaluated on every clip through the CLI
# with each worker count in WORKERS, and the breakdown of a scene's time per run
# (scripts/dev/closedloop_breakdown.py) with the GPU's utilisation over each run.
#   CLIPS=40 AGENTS="tcp camera" WORKERS="auto" [PROFILE=1] bash scripts/dev/device_closedloop.sh
set -euo pipefail
repo=$(pwd)
CLIPS="${CLIPS:-40}"
AGENTS="${AGENTS:-tcp camera}"
WORKERS="${WORKERS:-auto}"
EPOCHS="${EPOCHS:-2}"
DATA=/tmp/closedloop
start=$(date +%s)
if [ ! -f /tmp/drivee2e_env ]; then
    bash scripts/gpu_env.sh > /tmp/gpu_env.log 2>&1 || { tail -20 /tmp/gpu_env.log; exit 1; }
fi
# shellcheck disable=SC1091
source /tmp/drivee2e_env
export PATH="/tmp/proj/bin:$PATH"
echo "environment: $(( $(date +%s) - start )) s; $(nproc) cores; $(nvidia-smi -L | wc -l) GPUs"
cd /tmp
stage() { local t; t=$(date +%s); "$@" > /tmp/stage.log 2>&1 || { tail -20 /tmp/stage.log; exit 1; }
          echo "$1 $2: $(( $(date +%s) - t )) s"; }
if [ ! -f "$DATA/splits/default.csv" ]; then
    stage drivee2e synth --out "$DATA" --clips "$CLIPS" --seed 0 --workers "$(nproc)"
    stage drivee2e curate "$DATA"
    stage drivee2e collect "$DATA" --workers auto --sensor-hz 2
    stage drivee2e split "$DATA" --seed 0
fi
for agent in $AGENTS; do
    [ -f "$DATA/$agent.pt" ] || stage drivee2e train "$agent" "$DATA" --split all \
        --epochs "$EPOCHS" --out "$DATA/$agent.pt"
done
if [ -n "${PROFILE:-}" ]; then  # one worker in one process, profiled (the agent on the GPU)
    for agent in $AGENTS; do
        python3 "$repo/scripts/dev/profile_evaluate.py" "$DATA" --agent "$agent" \
            --checkpoint "$DATA/$agent.pt" --clips 2 --top 60 > "$OUT/profile-$agent.txt" 2>&1
        head -4 "$OUT/profile-$agent.txt"
    done
fi
runs=()
for agent in $AGENTS; do
    for workers in $WORKERS; do
        run="$DATA/runs/$agent-w$workers${TAG:-}"
        rm -rf "$run"
        nvidia-smi --query-gpu=utilization.gpu --format=csv,noheader,nounits -l 1 \
            > "/tmp/util-$agent-$workers" 2>/dev/null &
        logger=$!
        stage drivee2e evaluate "$DATA" --split all --agent "$agent" --checkpoint "$DATA/$agent.pt" \
            --workers "$workers" --out "$run"
        kill "$logger"
        echo "  GPU busy % (mean of 1 s samples): $(awk '{s+=$1; n++} END {printf "%.0f", s/n}' \
            "/tmp/util-$agent-$workers")"
        runs+=("$run")
    done
done
python3 "$repo/scripts/dev/closedloop_breakdown.py" "${runs[@]}"
mkdir -p "$OUT/runs"
for run in "${runs[@]}"; do
    cp "$run/episodes.parquet" "$OUT/runs/$(basename "$run").parquet"
done
