#!/usr/bin/env bash
# The main job on the embedded default: install, synthesise a small set of intersections and
# staged clips, curate them (track quality, behaviour labels), and list them with the dataset's
# distributions. Output goes to ./data (override with DATA=...).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
DATA="${DATA:-data}"
.venv/bin/drivee2e synth --out "$DATA" --clips "${CLIPS:-8}" --seed "${SEED:-0}"
.venv/bin/drivee2e curate "$DATA" > "$DATA/curation.txt"
echo "curation table: $DATA/curation.txt"
.venv/bin/drivee2e scenarios "$DATA" --stats
