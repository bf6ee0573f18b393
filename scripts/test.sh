#!/usr/bin/env bash
# Install everything, lint, and run the test suite. Fails on any failure.
#   bash scripts/test.sh          everything (what CI runs)
#   bash scripts/test.sh --quick  the edit-test loop: without the tests marked slow (end to end)
# pytest runs a worker per core (pytest-xdist), each test file on one worker (its module-scoped
# data made once); TEST_WORKERS=0 runs the tests in one process, as before.
set -euo pipefail
cd "$(dirname "$0")/.."
# The tests run the Ray backend too (on a local Ray) and the data module under Lightning. The
# environment is not byte-compiled at install: the tests' first imports write the bytecode of
# the modules the tests use (a fraction of torch's and the extras'), which every later process
# reads, even where the machine sets PYTHONDONTWRITEBYTECODE (install 31.8 -> 14.8 s, pytest
# +8 s on 2 cores).
DRIVEE2E_COMPILE=0 EXTRAS=dev,viz,ray,lightning bash scripts/install.sh
export PYTHONDONTWRITEBYTECODE=
# The official nuscenes-devkit checks the nuScenes export; its pins (numpy<2, shapely 2.0) clash
# with this package, so it gets an environment of its own: by the uv install.sh installed where
# it did (seconds, from uv's cache), else by pip.
if ! .venv-nuscenes/bin/python -c "import nuscenes" 2>/dev/null; then
    devkit="nuscenes-devkit==1.2.0"
    nuscenes_log="$(mktemp)"
    trap 'rm -f "$nuscenes_log"' EXIT
    if ! {
        [ -x .venv/bin/uv ] &&
            .venv/bin/uv venv --quiet --python "$(command -v python3)" .venv-nuscenes &&
            .venv/bin/uv pip install --quiet --python .venv-nuscenes/bin/python "$devkit"
    } >"$nuscenes_log" 2>&1; then
        rm -rf .venv-nuscenes
        {
            python3 -m venv .venv-nuscenes &&
                .venv-nuscenes/bin/python -m pip install --quiet --upgrade pip &&
                .venv-nuscenes/bin/python -m pip install --quiet "$devkit"
        } >>"$nuscenes_log" 2>&1 || {
            cat "$nuscenes_log" >&2
            echo "test.sh: the nuscenes-devkit environment (.venv-nuscenes) did not install (above)" >&2
            exit 1
        }
    fi
fi
.venv/bin/ruff check .
.venv/bin/ruff format --check .
# a crashed worker fails the run at once: replaced, its file's tests could leave the run
# waiting on them for good (seen once under --dist loadfile)
# the files dealt heaviest first, in the order tests/conftest.py gives them
workers=(-n "${TEST_WORKERS:-auto}" --dist loadfile --no-loadscope-reorder --max-worker-restart 0)
[ "${TEST_WORKERS:-auto}" = 0 ] && workers=(-p no:xdist)
if [ "${1:-}" = --quick ]; then
    .venv/bin/python -m pytest -q "${workers[@]}" -m "not slow"
else
    .venv/bin/python -m pytest -q "${workers[@]}"
fi
