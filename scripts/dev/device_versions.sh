#!/usr/bin/env bash
# A change's cost to collection on a fresh GPU host, in the background (setsid) so the run goes
# on between device calls: the real mix (`drivee2e synth --clips CLIPS --seed 0`, curated)
# collected whole through the CLI by the version in BASE_TAR and by this one, runs alternating
# (scripts/dev/bench_versions.py, REPEATS each), at 10 Hz and then with `--sensor-hz 2`.
# BASE_TAR holds the base version's files that differ from this one (`git archive REV $(git diff
# --name-only --diff-filter=MD REV HEAD -- drivee2e_data loaders collect) -o out/base.tar`).
#   BASE_TAR=out/base.tar BASE_NAME=REV bash scripts/dev/device_versions.sh && \
#       bash scripts/dev/device_versions.sh --wait 520   # the first call: start, then wait
#   bash scripts/dev/device_versions.sh --wait 540      # each later call, made at once
# Carry .gl, .whl, .pb and the BASE_TAR file. Each step's output goes to /tmp/versions/log.txt.
set -uo pipefail
RUN=/tmp/versions
LOG="$RUN/log.txt"
if [ "${1:-}" = --wait ]; then
    # shellcheck source=scripts/dev/device_wait.sh
    source "$(dirname "$0")/device_wait.sh"
    wait_for "^total:" "$LOG" "${2:-540}"
    cat "$LOG"
    [ -n "${OUT:-}" ] && cp "$LOG" "$OUT/log.txt"
    exit 0
fi
say() { echo "$*" >> "$LOG"; }
if [ "${1:-}" != --run ]; then  # set the host up, then the run in a session of its own
    [ -n "${BASE_TAR:-}" ] || { echo "BASE_TAR is required" >&2; exit 2; }
    rm -rf "$RUN" && mkdir -p "$RUN/repo"
    cp -r scripts "$RUN/repo/"
    start=$(date +%s)
    # shellcheck source=scripts/dev/device_env.sh
    source scripts/dev/device_env.sh  # the environment; the base version's files in /tmp/base_src
    say "environment: $(( $(date +%s) - start )) s; $(nproc) cores; $(nvidia-smi -L | wc -l) GPUs"
    echo "$start" > "$RUN/started"
    BASE_NAME="${BASE_NAME:-base}" CLIPS="${CLIPS:-16}" REPEATS="${REPEATS:-2}" \
        setsid bash "$RUN/repo/scripts/dev/device_versions.sh" --run > "$RUN/run.log" 2>&1 < /dev/null &
    echo "started; log: $LOG"
    exit 0
fi
# shellcheck disable=SC1091
source /tmp/drivee2e_env
export PATH="/tmp/proj/bin:$PATH"
cd /tmp || exit 1
start=$(cat "$RUN/started")
data="$RUN/data"
step=$(date +%s)
drivee2e synth --out "$data" --clips "$CLIPS" --seed 0 >> "$RUN/run.log" 2>&1 \
    && drivee2e curate "$data" >> "$RUN/run.log" 2>&1 \
    || { say "synthesis failed: $(tail -5 "$RUN/run.log")"; say "total: failed"; exit 1; }
say "synth and curate $CLIPS clips: $(( $(date +%s) - step )) s"
for rate in 10 2; do
    extra=()
    [ "$rate" = 2 ] && extra=(-- --sensor-hz 2)
    say "== sensors at $rate Hz, whole clips, base $BASE_NAME against this version"
    python3 "$RUN/repo/scripts/dev/bench_versions.py" --base "$BASE_NAME" --base-tree /tmp/base_src \
        --data "$data" --max-frames 0 --repeats "$REPEATS" "${extra[@]}" >> "$LOG" 2>&1 \
        || say "bench_versions failed at $rate Hz: $(tail -5 "$RUN/run.log")"
done
say "total: $(( $(date +%s) - start )) s"
