#!/usr/bin/env bash
# The main job on the embedded default: install, synthesise a small set of intersections and
# staged clips, and list them. Output goes to ./data (override with DATA=...).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
DATA="${DATA:-data}"
.venv/bin/drivee2e synth --out "$DATA" --clips "${CLIPS:-8}" --seed "${SEED:-0}"
.venv/bin/drivee2e scenarios "$DATA"
