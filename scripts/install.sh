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
# The CommonRoad importer uses commonroad-io's XML reader only. commonroad-io pins
# protobuf==3.20, which the MCAP stack cannot use, so it goes in without its own requirements,
# after the ones its XML reader needs: installed last and with --no-deps, pip has no conflict
# to report (installed earlier, every later pip call printed a resolver ERROR about the pin).
python -m pip install --quiet "omegaconf>=2.1" "iso3166>=1.0" "lxml>=4.2" "networkx>=2.2" "rtree>=0.8" "scipy>=1.11" "pillow>=10.4"
python -m pip install --quiet --no-deps "commonroad-io==2026.1" "commonroad-vehicle-models==3.0.2"
