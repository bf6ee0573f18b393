#!/usr/bin/env bash
# A two-node Ray cluster on one machine: two `ray start` processes, each with its own CPUs and a
# resource naming it, collect one set of clips across both (`drivee2e collect --backend ray`);
# then every log is validated and compared byte for byte with a one-worker run of the same clip.
#
#   bash scripts/ray_two_nodes.sh [CLIPS] [FRAMES] [CPUS_PER_NODE]     # defaults: 4 50 1
#
# Needs the ray extra (EXTRAS=dev,viz,ray bash scripts/install.sh). Leaves its data in a
# temporary folder that it names, and stops both nodes whatever happens.
set -euo pipefail
cd "$(dirname "$0")/.."
CLIPS=${1:-4}
FRAMES=${2:-50}
CPUS=${3:-1}
PORT=${RAY_PORT:-6390}
BIN=$PWD/.venv/bin
export PATH=$BIN:$PATH
WORK=$(mktemp -d /tmp/ray_two_nodes.XXXXXX)
echo "work folder: $WORK"

stop_nodes() { ray stop --force >/dev/null 2>&1 || true; }
trap stop_nodes EXIT
stop_nodes
ray start --head --port="$PORT" --num-cpus="$CPUS" --resources='{"node_a": 1}' \
    --include-dashboard=false --disable-usage-stats >"$WORK/node_a.log" 2>&1
ray start --address="127.0.0.1:$PORT" --num-cpus="$CPUS" --resources='{"node_b": 1}' \
    --disable-usage-stats >"$WORK/node_b.log" 2>&1
for _ in $(seq 30); do  # the second node registers with the head within seconds
    if ray status --address="127.0.0.1:$PORT" 2>/dev/null | grep -q node_b; then break; fi
    sleep 1
done
ray status --address="127.0.0.1:$PORT" | sed -n '/Active:/,/Pending:/p;/Total Usage/,/object_store/p'

drivee2e synth --out "$WORK/ray" --clips "$CLIPS" --seed 0 >/dev/null
drivee2e curate "$WORK/ray" >/dev/null
mkdir -p "$WORK/alone"
cp -r "$WORK/ray/maps" "$WORK/ray/scenarios" "$WORK/alone/"

start=$(date +%s.%N)
RAY_ADDRESS="127.0.0.1:$PORT" drivee2e collect "$WORK/ray" --backend ray --max-frames "$FRAMES"
echo "two-node Ray run: $(echo "$(date +%s.%N) - $start" | bc) s including joining the cluster"
drivee2e logs "$WORK/ray" --validate
stop_nodes

drivee2e collect "$WORK/alone" --workers 1 --max-frames "$FRAMES"
same=0
for log in "$WORK"/alone/logs/*.mcap; do
    if cmp -s "$log" "$WORK/ray/logs/$(basename "$log")"; then same=$((same + 1)); fi
done
total=$(ls "$WORK"/alone/logs/*.mcap | wc -l)
echo "byte-identical to a one-worker run: $same of $total logs"
[ "$same" -eq "$total" ]
