#!/usr/bin/env bash
# One GPU host, from a fresh machine: its environment (scripts/gpu_env.sh), then Benchmark v1
# (scripts/benchmark.sh) with the settings given in the environment, in the background (setsid)
# so that a run longer than one device call goes on between calls; the GPU's utilisation logged
# every second. Then `bash scripts/dev/device_benchmark.sh --wait SECONDS` waits, prints progress,
# and packs what a person reads (report, stage times, summaries, logs, GPU log) into $OUT, the
# report of what is scored so far where the run has not finished.
#   bash scripts/dev/device_benchmark.sh            # start (run from the repository root)
#   bash scripts/dev/device_benchmark.sh --wait 540 # later calls
# Carry .gl, .whl and .pb (scripts/gpu_env.sh installs from them; the host reaches no index).
# A machine stays warm only 30 s after a call returns: a later call that comes after that finds
# a fresh machine without the run (2026-11-28: a 530 s wait spent on a bare host), so start and
# wait in the first call where the run fits in one (`... device_benchmark.sh && bash
# scripts/dev/device_benchmark.sh --wait 500`), and make each later call at once.
set -uo pipefail
RUN=/tmp/bench
HERE="$(cd "$(dirname "$0")" && pwd)"
if [ "${1:-}" != --wait ]; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
    start=$(date +%s)
    bash scripts/gpu_env.sh > /tmp/gpu_env.log 2>&1 || { tail -20 /tmp/gpu_env.log; exit 1; }
    echo "environment: $(( $(date +%s) - start )) s"
    # shellcheck disable=SC1091
    source /tmp/drivee2e_env
    setsid nvidia-smi --query-gpu=timestamp,index,utilization.gpu,memory.used --format=csv,noheader \
        -l 1 > /tmp/gpu_util.csv 2>/dev/null &
    repo=$(pwd)
    cd /tmp || exit 1
    setsid env PATH="/tmp/proj/bin:$PATH" DRIVEE2E=drivee2e PYTHON=python3 \
        bash "$repo/scripts/benchmark.sh" "$RUN" > /tmp/bench.log 2>&1 < /dev/null &
    echo "started benchmark.sh in the background"
    exit 0
fi
# shellcheck source=scripts/dev/device_wait.sh
source "$(dirname "$0")/device_wait.sh"
wait_for "^## Benchmark v1" /tmp/bench.log "${2:-540}"
grep "^== " /tmp/bench.log | tail -40
grep -i -E "error|traceback" /tmp/bench.log | head -5
# what a person reads, finished or not (a later call brings a newer copy)
finished=no
grep -q "^## Benchmark v1" /tmp/bench.log && finished=yes
echo "finished: $finished"
if [ "$finished" = no ] && [ -d "$RUN/runs" ]; then  # the report of what is scored so far
    (cd /tmp && python3 "$HERE/../benchmark_report.py" "$RUN" > /tmp/partial_report.txt 2>&1)
    cp /tmp/partial_report.txt "$OUT/report.txt"
else
    cp /tmp/bench.log "$OUT/report.txt"
fi
cp /tmp/bench.log "$OUT/bench.log" 2>/dev/null
cp /tmp/gpu_util.csv "$OUT/gpu_util.csv" 2>/dev/null
(cd "$RUN" && tar -czf "$OUT/results.tar.gz" times.tsv report.md scaling.png manifests \
    runs/*/summary.json runs/*/episodes.parquet openloop/*.json logs checkpoints/*.done \
    checkpoints/*.failed 2>/dev/null)
# the first eight episodes' MP4s of each recorded run (the largest size's), to look at
(cd "$RUN" && find runs -path "*/records/*.mp4" 2>/dev/null | sort | awk -F/ 'n[$2]++ < 8' \
    | tar -cf "$OUT/episodes_mp4.tar" -T - 2>/dev/null)
ls -la "$OUT"
