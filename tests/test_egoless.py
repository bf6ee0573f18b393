"""Sources without a usable ego: an import of clips with no motor vehicle says so and writes none
unless asked; curate counts the clips without an ego and why; collect lists what it skips."""

from __future__ import annotations

from pathlib import Path

import pytest

from drivee2e_data import store
from drivee2e_data.cli import main
from drivee2e_data.collect.job import CollectOptions
from drivee2e_data.collect.runner import collect
from drivee2e_data.scenario import AgentClass
from tests.factories import small_map, small_scenario, straight_track


def test_collect_skips_and_lists_clips_without_an_ego(tmp_path: Path, capsys):
    walkers = (straight_track("w", 5, AgentClass.PEDESTRIAN),)
    store.write_map(tmp_path, small_map())
    store.write_scenario(tmp_path, small_scenario(5, tracks=walkers, ego_id=None))
    summary = collect(tmp_path, CollectOptions(max_frames=1))
    assert [(r.scenario_id, r.status) for r in summary.results] == [("tiny", "no ego")]
    assert not list((tmp_path / "logs").glob("*.mcap"))
    assert main(["collect", str(tmp_path), "--max-frames", "1", "--lidar", "raycast"]) == 0
    assert "1 clips skipped, no ego to mount the rig on" in capsys.readouterr().out


def test_sind_pedestrians_only_write_no_egoless_clips_unless_asked(tmp_path: Path, capsys):
    from conftest import REALDATA

    source = REALDATA / "sind" / "Data" / "Tianjin"
    if not source.exists():
        pytest.skip(f"{source} is absent (../shared/realdata)")
    assert main(["import", "sind", str(source), "--out", str(tmp_path / "default")]) == 0
    out = capsys.readouterr().out
    assert "no clip has an ego: all" in out and "not written (--keep-egoless writes them)" in out
    assert store.scenario_ids(tmp_path / "default") == []
    kept = tmp_path / "kept"
    assert main(["import", "sind", str(source), "--out", str(kept), "--keep-egoless"]) == 0
    clips = store.scenario_ids(kept)
    assert clips
    capsys.readouterr()
    assert main(["curate", str(kept)]) == 0
    assert f"{len(clips)} without an ego: no vehicle" in capsys.readouterr().out
    assert main(["scenarios", str(kept), "--stats"]) == 0
    out = capsys.readouterr().out
    assert f"clips without an ego: {len(clips)}; {len(clips)}: no motor vehicle in the clip" in out
