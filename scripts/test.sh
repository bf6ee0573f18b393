#!/usr/bin/env bash
# Install everything, lint, and run the test suite. Fails on any failure.
set -euo pipefail
cd "$(dirname "$0")/.."
# the tests run the Ray backend too, on a local Ray
EXTRAS=dev,viz,ray bash scripts/install.sh
.venv/bin/ruff check .
.venv/bin/ruff format --check .
.venv/bin/python -m pytest -q
