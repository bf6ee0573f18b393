#!/usr/bin/env bash
# The learning side's short commands with two versions of the code, alternating, each run from
# no feature cache: AD-MLP's cache of the train split, then constant velocity's predict (from its
# cache) and openloop (both conventions; the first builds the scoring cache, then again), through
# `python -m drivee2e_data.cli` with each version's files first on PYTHONPATH. Prints each
# run's seconds; checks that both versions write the same open-loop JSON.
#   git archive REV | tar -x -C BASE_TREE
#   bash scripts/dev/bench_openloop.sh BASE_TREE DATA [RUNS]
# DATA: collected and split (`drivee2e split`); its features/ folder is removed before each run.
# `python3` is the environment that has the package installed (for example .venv/bin first on
# PATH).
set -euo pipefail
BASE_TREE="${1:?usage: bench_openloop.sh BASE_TREE DATA [RUNS]}"
DATA="${2:?usage: bench_openloop.sh BASE_TREE DATA [RUNS]}"
RUNS="${3:-2}"
WORK="$(cd "$(dirname "$0")/../.." && pwd)"
OUT="$(mktemp -d)"
cli() {  # cli TREE ARGS...: the CLI of the version in TREE, from outside any checkout
    local tree="$1"
    shift
    (cd /tmp && PYTHONPATH="$tree" python3 -m drivee2e_data.cli "$@" > /dev/null 2>&1)
}
seconds() { python3 -c "import time; print(time.monotonic())"; }
run() {  # run NAME TREE
    local name="$1" tree="$2" t0 t1 t2 t3 t4 t5
    rm -rf "$DATA/features"
    t0=$(seconds); cli "$tree" cache "$DATA" --model admlp --split train --workers 2
    t1=$(seconds); cli "$tree" predict "$DATA" --split val --model constant-velocity \
        --out "$OUT/$name.parquet"
    t2=$(seconds); cli "$tree" predict "$DATA" --split val --model constant-velocity \
        --out "$OUT/$name.parquet"
    t3=$(seconds)
    for _ in first again; do
        cli "$tree" openloop "$DATA" --split val --predictions "$OUT/$name.parquet" \
            --convention stp3 uniad --json "$OUT/${name}_{convention}.json"
        [ -n "${t4:-}" ] || t4=$(seconds)
    done
    t5=$(seconds)
    python3 -c "print('$name: cache admlp train %.1f s, predict %.1f s (the first, building \
its cache, %.1f), openloop %.1f s (the first, building the scoring cache, %.1f)' % \
($t1 - $t0, $t3 - $t2, $t2 - $t1, $t5 - $t4, $t4 - $t3))"
}
for (( i = 0; i < RUNS; i++ )); do
    run base "$BASE_TREE"
    run work "$WORK"
done
for convention in stp3 uniad; do
    cmp "$OUT/base_$convention.json" "$OUT/work_$convention.json"
done
echo "the same open-loop JSON from both versions"
rm -rf "$OUT"
