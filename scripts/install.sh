#!/usr/bin/env bash
# Creates .venv and installs drivee2e-data with its test and plotting extras.
# On a machine without a GPU the CPU build of torch goes in first, so pip does not pull a
# multi-GB CUDA build. A GPU user sets TORCH_SPEC (for example "torch --index-url
# https://download.pytorch.org/whl/cu124") to choose the build instead.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
. .venv/bin/activate
python -m pip install --quiet --upgrade pip
# shellcheck disable=SC2086
python -m pip install --quiet ${TORCH_SPEC:-torch==2.13.0}
python -m pip install --quiet -e ".[dev,viz]"
