#!/usr/bin/env bash
# Creates .venv and installs drivee2e-data with its test and plotting extras.
# On a machine without a GPU the CPU build of torch goes in first, so pip does not pull a
# multi-GB CUDA build. EXTRAS picks the optional extras (default dev,viz; the tests add ray).
# A GPU user sets TORCH_SPEC (for example "torch --index-url
# https://download.pytorch.org/whl/cu124") to choose the build instead.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
. .venv/bin/activate
python -m pip install --quiet --upgrade pip
# shellcheck disable=SC2086
python -m pip install --quiet ${TORCH_SPEC:-torch==2.13.0}
python -m pip install --quiet -e ".[${EXTRAS:-dev,viz}]"
# The package's own modules byte-compiled now: an editable install leaves them to Python, and
# where PYTHONDONTWRITEBYTECODE is set (as on this project's machines) every process compiled
# them again on import (0.25 s of a collection or evaluation worker's start on 2 cores). A
# module edited later is compiled in memory until this runs again.
python -m compileall -q -j 0 drivee2e_data collect loaders > /dev/null
# The CommonRoad importer uses commonroad-io's XML reader only. commonroad-io pins
# protobuf==3.20, which the MCAP stack cannot use, so it goes in without its own requirements,
# after the ones its XML reader needs: installed last and with --no-deps, pip has no conflict
# to report (installed earlier, every later pip call printed a resolver ERROR about the pin).
python -m pip install --quiet "omegaconf>=2.1" "iso3166>=1.0" "lxml>=4.2" "networkx>=2.2" "rtree>=0.8" "scipy>=1.11" "pillow>=10.4"
python -m pip install --quiet --no-deps "commonroad-io==2026.1" "commonroad-vehicle-models==3.0.2"
# Without a GPU, Mesa's llvmpipe draws the cameras. Mesa 25 (Debian 12's bookworm-backports, the
# same LLVM) draws the same images as Debian 12's own Mesa 22.3 in about four fifths of the time
# (docs/benchmarks.md), so it is fetched into .venv/mesa, where drivee2e finds it; it stays off
# wherever a GPU's EGL vendor is installed. DRIVEE2E_FETCH_MESA=0 skips this; a fetch that fails
# (no network, not Debian 12 or alike) only warns: the system's Mesa then draws.
if [ "${DRIVEE2E_FETCH_MESA:-1}" != 0 ] && [ "$(uname -s)" = Linux ] && [ ! -f .venv/mesa/mesa.json ]; then
    .venv/bin/drivee2e mesa --fetch --folder .venv/mesa \
        || echo "install.sh: Mesa 25 not fetched (above); the system's Mesa will draw" >&2
fi
