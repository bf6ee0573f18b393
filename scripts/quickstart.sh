#!/usr/bin/env bash
# The main job on the embedded default: install, synthesise a small set of intersections and
# staged clips, curate them (track quality, behaviour labels), collect expert data with the full
# sensor suite into one MCAP log per clip, split the clips 2:1:1, score two open-loop
# baselines (constant velocity; AD-MLP trained on the train split) on the val split through the
# torch data module, then drive the val clips in closed loop with the log-replay expert,
# constant velocity, AD-MLP and the camera policy (Success Rate, Driving Score). Output goes to
# ./data.
#   DATA=...      data root (default data)
#   CLIPS=N       clips to synthesise (default 4)
#   FRAMES=N      frames collected per clip (default 50, 5 s); FRAMES=all for whole clips
#   WORKERS=N     collector processes (default: the number of cores, at most 4)
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
DATA="${DATA:-data}"
FRAMES="${FRAMES:-50}"
CORES="$(getconf _NPROCESSORS_ONLN 2>/dev/null || echo 2)"
WORKERS="${WORKERS:-$(( CORES < 4 ? CORES : 4 ))}"
.venv/bin/drivee2e synth --out "$DATA" --clips "${CLIPS:-4}" --seed "${SEED:-0}"
.venv/bin/drivee2e curate "$DATA" > "$DATA/curation.txt"
echo "curation table: $DATA/curation.txt"
.venv/bin/drivee2e scenarios "$DATA" --stats
LIMIT=()
if [ "$FRAMES" != "all" ]; then LIMIT=(--max-frames "$FRAMES"); fi
.venv/bin/drivee2e collect "$DATA" --workers "$WORKERS" "${LIMIT[@]}"
.venv/bin/drivee2e logs "$DATA" --validate
.venv/bin/drivee2e split "$DATA" --seed "${SEED:-0}"
bash scripts/openloop_baselines.sh "$DATA" val
bash scripts/closedloop_baselines.sh "$DATA" val
