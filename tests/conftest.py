"""Shared fixtures: one synthetic data root per test session, made through the CLI."""

from __future__ import annotations

from pathlib import Path

import pytest

from drivee2e_data import store
from drivee2e_data.cli import main

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
DEFAULT_CLIPS = 12


@pytest.fixture(scope="session")
def synthetic_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The default set: `drivee2e synth --clips 12 --seed 0`."""
    root = tmp_path_factory.mktemp("synth") / "data"
    assert main(["synth", "--out", str(root), "--clips", str(DEFAULT_CLIPS), "--seed", "0"]) == 0
    return root


@pytest.fixture(scope="session")
def synthetic_scenarios(synthetic_root: Path) -> list:
    return [store.read_scenario(synthetic_root, i) for i in store.scenario_ids(synthetic_root)]
