#!/usr/bin/env bash
# Closed-loop speed on a fresh GPU host (issue 60's measurement), in one device call: its
# environment (scripts/gpu_env.sh), CLIPS synthetic clips (seed 0), an agent checkpoint (TCP and
# the camera policy trained briefly on the clips collected at 2 Hz, or TCP from a carried
# half-precision copy: HALF_TCP=out/tcp_half.pt, its optimiser state remade to a real
# checkpoint's size; the network's cost does not depend on how well it is trained), then each
# agent evaluated on every clip through the CLI with each worker count in WORKERS, by this
# version and, with BASE_TAR (carried: `git archive REV $(git diff --name-only REV -- drivee2e_data
# loaders collect) -o out/base.tar`, the files that differ), by that one first,
# and the breakdown of a scene's time per run (scripts/dev/closedloop_breakdown.py) with the
# GPU's utilisation over each run. VARIANTS names more runs of this version, each with its
# environment: "NAME:VAR=VALUE,VAR=VALUE" (e.g. the policy server as before,
# "oldserver:DRIVEE2E_GATHER_MS=2,DRIVEE2E_WORKER_NICENESS=0").
# TIMELINE=1 runs each evaluation through scripts/dev/start_timeline.py (its summary and each
# wrapped function's calls printed, its raw timeline kept; TIMELINE_STEPS=1: every step's too,
# tabulated over the run). What a call brings back is one archive, $OUT/closedloop.tar.gz
# (runs/: each run's episodes and its servers' accounts; the timelines and profiles): a device
# call returns only a few files. SAVE_INPUTS=1 also writes $OUT/closedloop_inputs.tar (the
# clips' scenarios, maps and split, and TCP's checkpoint in half precision); carried back as
# INPUTS=out/closedloop_inputs.tar it replaces synthesis, curation, collection and TCP's
# training (about 100 s of a cold call; AGENTS="tcp" only, DS then that checkpoint's).
# ROUNDS=N runs every version (and variant) N times in turn, base first (run folders -rK):
# hosts of one kind differ by up to 1.17x in a day, so versions compare pair by pair in a call.
#   CLIPS=40 AGENTS="tcp camera" WORKERS="auto" [PROFILE=1] [TIMELINE=1 [TIMELINE_STEPS=1]]
#   [BASE_TAR=out/base_overlay.tar] [HALF_TCP=out/tcp_half.pt] [VARIANTS="..."]
#   [SAVE_INPUTS=1 | INPUTS=out/closedloop_inputs.tar] [ROUNDS=2] bash scripts/dev/device_closedloop.sh
set -euo pipefail
repo=$(pwd)
CLIPS="${CLIPS:-40}"
AGENTS="${AGENTS:-tcp camera}"
WORKERS="${WORKERS:-auto}"
EPOCHS="${EPOCHS:-2}"
DATA=/tmp/closedloop
start=$(date +%s)
# shellcheck source=scripts/dev/device_env.sh
source "$repo/scripts/dev/device_env.sh"  # the environment; `versions`
echo "environment: $(( $(date +%s) - start )) s; $(nproc) cores; $(nvidia-smi -L | wc -l) GPUs"
cd /tmp
if [ -n "${INPUTS:-}" ] && [ ! -f "$DATA/splits/default.csv" ]; then  # SAVE_INPUTS' archive
    rm -rf /tmp/closedloop_inputs && mkdir -p /tmp/closedloop_inputs "$DATA"
    tar -xf "$repo/$INPUTS" -C /tmp/closedloop_inputs
    cp -r /tmp/closedloop_inputs/data/. "$DATA/"
    HALF_TCP="${HALF_TCP:-/tmp/closedloop_inputs/tcp_half.pt}"
fi
stage() { local t=$EPOCHREALTIME; "$@" > /tmp/stage.log 2>&1 || { tail -20 /tmp/stage.log; exit 1; }
          echo "$(awk -v a="$t" -v b="$EPOCHREALTIME" 'BEGIN {printf "%.1f", b - a}') s: $*" | cut -c1-110; }
if [ ! -f "$DATA/splits/default.csv" ]; then
    stage drivee2e synth --out "$DATA" --clips "$CLIPS" --seed 0 --workers "$(nproc)"
    stage drivee2e curate "$DATA"
    [ -n "${HALF_TCP:-}" ] || stage drivee2e collect "$DATA" --workers auto --sensor-hz 2
    stage drivee2e split "$DATA" --seed 0
fi
if [ -n "${HALF_TCP:-}" ] && [ ! -f "$DATA/tcp.pt" ]; then
    [[ "$HALF_TCP" == /* ]] || HALF_TCP="$repo/$HALF_TCP"
    python3 - "$HALF_TCP" "$DATA/tcp.pt" <<'PY'
import sys

import torch

saved = torch.load(sys.argv[1], map_location="cpu", weights_only=True)
model = {k: v.float() if v.is_floating_point() else v for k, v in saved["model"].items()}
saved["model"] = model
floats = [v for v in model.values() if v.is_floating_point()]
saved["optimiser"] = {  # Adam's two moments per parameter, as a trained checkpoint holds
    "state": {i: {"exp_avg": v.clone(), "exp_avg_sq": v.clone(), "step": torch.tensor(1.0)}
              for i, v in enumerate(floats)},
    "param_groups": [{"lr": 3e-4, "params": list(range(len(floats)))}],
}
torch.save(saved, sys.argv[2])
PY
fi
for agent in $AGENTS; do
    [ "$agent" = constant-velocity ] || [ -f "$DATA/$agent.pt" ] || stage drivee2e train "$agent" "$DATA" --split all \
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
      for round in $(seq 1 "${ROUNDS:-1}"); do
        for version in "${versions[@]}" ${VARIANTS:-}; do
            name="${version%%:*}"
            variables=()
            [[ "$version" == *:* ]] && IFS=, read -r -a variables <<< "${version#*:}"
            run="$DATA/runs/$agent-w$workers-$name"
            [ "${ROUNDS:-1}" = 1 ] || run="$run-r$round"
            checkpoint=(--checkpoint "$DATA/$agent.pt")  # constant velocity reads none
            [ "$agent" = constant-velocity ] && checkpoint=()
            rm -rf "$run"
            nvidia-smi --query-gpu=utilization.gpu --format=csv,noheader,nounits -l 1 \
                > "/tmp/util-$agent-$workers" 2>/dev/null &
            logger=$!
            path=/tmp/proj
            [ "$version" = base ] && path=/tmp/proj_base
            timeline=()  # TIMELINE=1: where the command's start went (start_timeline.py)
            [ -z "${TIMELINE:-}" ] || timeline=(python3 "$repo/scripts/dev/start_timeline.py"
                --log "$OUT/timeline-$(basename "$run").log" --durations ${TIMELINE_STEPS:+--steps} --)
            stage env "${variables[@]}" PYTHONPATH="$path:/tmp/site" "${timeline[@]}" \
                python3 -m drivee2e_data.cli evaluate "$DATA" \
                --split all --agent "$agent" "${checkpoint[@]}" --workers "$workers" \
                --out "$run"
            [ -z "${TIMELINE:-}" ] || sed 's/^/  /' /tmp/stage.log
            kill "$logger"
            echo "  $(basename "$run"): GPU busy % (mean of 1 s samples): $(awk '{s+=$1; n++} END \
                {printf "%.0f", s/n}' "/tmp/util-$agent-$workers")"
            runs+=("$run")
        done
      done
    done
done
python3 "$repo/scripts/dev/closedloop_breakdown.py" "${runs[@]}"
rm -rf /tmp/closedloop_out && mkdir -p /tmp/closedloop_out/runs
for run in "${runs[@]}"; do
    cp "$run/episodes.parquet" "/tmp/closedloop_out/runs/$(basename "$run").parquet"
    for stats in "$run"/policy_server_*.json; do
        [ -f "$stats" ] && cp "$stats" "/tmp/closedloop_out/runs/$(basename "$run")-$(basename "$stats")"
    done
done
for kept in "$OUT"/timeline-*.log "$OUT"/profile-*.txt; do
    [ -f "$kept" ] && mv "$kept" /tmp/closedloop_out/
done
tar -czf "$OUT/closedloop.tar.gz" -C /tmp/closedloop_out .
if [ -n "${SAVE_INPUTS:-}" ] && [ -f "$DATA/tcp.pt" ]; then
    rm -rf /tmp/closedloop_save && mkdir -p /tmp/closedloop_save/data
    cp -r "$DATA/maps" "$DATA/scenarios" "$DATA/splits" /tmp/closedloop_save/data/
    python3 - "$DATA/tcp.pt" /tmp/closedloop_save/tcp_half.pt <<'PY'
import sys

import torch

saved = torch.load(sys.argv[1], map_location="cpu", weights_only=True)
saved["model"] = {k: v.half() if v.is_floating_point() else v for k, v in saved["model"].items()}
saved.pop("optimiser", None)  # remade where it is read (HALF_TCP)
torch.save(saved, sys.argv[2])
PY
    tar -cf "$OUT/closedloop_inputs.tar" -C /tmp/closedloop_save data tcp_half.pt
    echo "inputs: $(du -h "$OUT/closedloop_inputs.tar" | cut -f1) (INPUTS=out/closedloop_inputs.tar)"
fi
