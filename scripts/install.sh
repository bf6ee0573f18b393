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

# Everything, through the installer given (its command and options up to the packages); it
# returns at the first step that fails (errexit does not hold where the caller tests it).
install_all() {
    # shellcheck disable=SC2086
    "$@" ${TORCH_SPEC:-torch==2.13.0} || return 1
    "$@" -e ".[${EXTRAS:-dev,viz}]" || return 1
    # The CommonRoad importer uses commonroad-io's XML reader only. commonroad-io pins
    # protobuf==3.20, which the MCAP stack cannot use, so it goes in without its own
    # requirements, after the ones its XML reader needs: installed last and with --no-deps, pip
    # has no conflict to report (installed earlier, every later pip call printed a resolver
    # ERROR about the pin).
    "$@" "omegaconf>=2.1" "iso3166>=1.0" "lxml>=4.2" "networkx>=2.2" "rtree>=0.8" "scipy>=1.11" "pillow>=10.4" || return 1
    "$@" --no-deps "commonroad-io==2026.1" "commonroad-vehicle-models==3.0.2"
}

# uv installs the same packages in about two fifths of pip's time (downloads, unpacking and
# byte-compiling in parallel: 79 -> 35 s for the test command's environment on the 2-core
# machine, docs/benchmarks.md). It reads none of pip's settings, so the ones pip has here
# (find-links, constraints) are handed to it. DRIVEE2E_INSTALLER=pip keeps to pip; where uv
# cannot be had or fails, pip installs everything as before.
installed=""
if [ "${DRIVEE2E_INSTALLER:-uv}" != pip ] && python -m pip install --quiet uv 2>/dev/null; then
    uv_options=(--quiet --python .venv/bin/python)
    # byte-compiled at install (PYTHONDONTWRITEBYTECODE machines compile every import in
    # memory otherwise), unless DRIVEE2E_COMPILE=0 leaves it to the first imports (the tests)
    [ "${DRIVEE2E_COMPILE:-1}" = 0 ] || uv_options+=(--compile-bytecode)
    # pip's settings from its environment variables and its config files, and its certificates
    [ -z "${PIP_CERT:-}" ] || export SSL_CERT_FILE="${SSL_CERT_FILE:-$PIP_CERT}"
    for link in ${PIP_FIND_LINKS:-} $(python -m pip config get global.find-links 2>/dev/null || true); do
        uv_options+=(--find-links "$link")
    done
    for file in ${PIP_CONSTRAINT:-} $(python -m pip config get global.constraint 2>/dev/null || true); do
        uv_options+=(--constraint "$file")
    done
    if install_all .venv/bin/uv pip install "${uv_options[@]}"; then
        installed=uv
    else
        echo "install.sh: uv failed (above); installing with pip" >&2
    fi
fi
if [ -z "$installed" ]; then
    install_all python -m pip install --quiet || exit 1
fi
# The package's own modules byte-compiled now: an editable install leaves them to Python, and
# where PYTHONDONTWRITEBYTECODE is set (as on this project's machines) every process compiled
# them again on import (0.25 s of a collection or evaluation worker's start on 2 cores). A
# module edited later is compiled in memory until this runs again.
python -m compileall -q -j 0 drivee2e_data collect loaders > /dev/null
# Without a GPU, Mesa's llvmpipe draws the cameras. Mesa 25 (Debian 12's bookworm-backports, the
# same LLVM) draws the same images as Debian 12's own Mesa 22.3 in about four fifths of the time
# (docs/benchmarks.md), so it is fetched into .venv/mesa, where drivee2e finds it; it stays off
# wherever a GPU's EGL vendor is installed. DRIVEE2E_FETCH_MESA=0 skips this; a fetch that fails
# (no network, not Debian 12 or alike) only warns: the system's Mesa then draws.
if [ "${DRIVEE2E_FETCH_MESA:-1}" != 0 ] && [ "$(uname -s)" = Linux ] && [ ! -f .venv/mesa/mesa.json ]; then
    .venv/bin/drivee2e mesa --fetch --folder .venv/mesa \
        || echo "install.sh: Mesa 25 not fetched (above); the system's Mesa will draw" >&2
fi
