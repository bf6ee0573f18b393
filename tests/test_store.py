import hashlib
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from factories import small_map, small_scenario

from drivee2e_data import store
from drivee2e_data.cli import main
from drivee2e_data.errors import ScenarioFormatError, SchemaVersionError


def _snapshot(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


@pytest.fixture
def tiny_root(tmp_path: Path) -> Path:
    store.write_map(tmp_path, small_map())
    store.write_scenario(tmp_path, small_scenario())
    return tmp_path


def test_tiny_round_trip(tiny_root: Path):
    assert store.scenario_ids(tiny_root) == ["tiny"]
    assert store.read_scenario(tiny_root, "tiny") == small_scenario()
    assert store.read_map(tiny_root, "tiny_map") == small_map()


def test_invalid_frames_round_trip(tmp_path: Path):
    scenario = small_scenario()
    track = scenario.tracks[0]
    valid = np.array([False, True, False, True, False])
    gappy = type(track)(
        **{**track.__dict__, "valid": valid, "x_m": np.where(valid, track.x_m, np.nan)}
    )
    scenario = small_scenario(tracks=(gappy, scenario.tracks[1]))
    store.write_map(tmp_path, small_map())
    store.write_scenario(tmp_path, scenario)
    assert store.read_scenario(tmp_path, "tiny") == scenario


def test_every_synthetic_scenario_round_trips(
    synthetic_root: Path, synthetic_scenarios, tmp_path: Path
):
    for scenario in synthetic_scenarios:
        store.write_scenario(tmp_path, scenario)
        assert store.read_scenario(tmp_path, scenario.scenario_id, require_map=False) == scenario
    for map_id in store.map_ids(synthetic_root):
        intersection_map = store.read_map(synthetic_root, map_id)
        store.write_map(tmp_path, intersection_map)
        assert store.read_map(tmp_path, map_id) == intersection_map


def test_rewrite_replaces_bundle_and_leaves_no_temporaries(tiny_root: Path):
    store.write_scenario(tiny_root, small_scenario(ego_id="b"))
    assert store.read_scenario(tiny_root, "tiny").ego_id == "b"
    leftovers = [p.name for p in (tiny_root / "scenarios").iterdir() if p.name.startswith(".")]
    assert leftovers == []


def test_failed_write_leaves_old_bundle_untouched(tiny_root: Path, monkeypatch):
    before = _snapshot(tiny_root)

    def explode(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(store.pq, "write_table", explode)
    with pytest.raises(OSError, match="disk full"):
        store.write_scenario(tiny_root, small_scenario(ego_id="b"))
    assert _snapshot(tiny_root) == before


def test_newer_schema_is_refused(tiny_root: Path):
    meta_file = tiny_root / "scenarios" / "tiny" / "meta.json"
    meta = json.loads(meta_file.read_text())
    meta["schema_version"] = store.SCHEMA_VERSION + 1
    meta_file.write_text(json.dumps(meta))
    with pytest.raises(SchemaVersionError, match=r"meta.json: written by schema version 2"):
        store.read_scenario(tiny_root, "tiny")


def _rewrite_tracks(root: Path, change) -> None:
    path = root / "scenarios" / "tiny" / "tracks.parquet"
    table = pq.read_table(path).to_pydict()
    change(table)
    pq.write_table(pa.table(table), path)


def _set(column: str, row: int, value):
    def change(table):
        table[column][row] = value

    return change


def _swap_times(table):
    table["t_ns"][1], table["t_ns"][2] = table["t_ns"][2], table["t_ns"][1]


def _duplicate_row(table):
    for column in table:
        table[column].insert(2, table[column][1])
        table[column].pop()


def _truncate(root: Path) -> None:
    path = root / "scenarios" / "tiny" / "tracks.parquet"
    path.write_bytes(path.read_bytes()[:200])


def _drop_map(root: Path) -> None:
    (root / "maps" / "tiny_map.json").unlink()


BAD_INPUTS = {
    "nan position": (
        lambda root: _rewrite_tracks(root, _set("x", 3, float("nan"))),
        r"tracks.parquet row 3: column 'x' is nan for track 'a'",
    ),
    "non-increasing timestamp": (
        lambda root: _rewrite_tracks(root, _swap_times),
        r"tracks.parquet row 2: track 'a' at t_ns \d+ is out of time order",
    ),
    "duplicate track row": (
        lambda root: _rewrite_tracks(root, _duplicate_row),
        r"tracks.parquet row 2: track 'a' at t_ns \d+ duplicates an earlier row",
    ),
    "unknown class": (
        lambda root: _rewrite_tracks(root, _set("class", 0, "hovercraft")),
        r"tracks.parquet row 0: column 'class' is 'hovercraft' for track 'a'",
    ),
    "truncated parquet": (_truncate, r"tracks.parquet: not a readable Parquet file"),
    "missing map": (_drop_map, r"meta.json: map_id 'tiny_map' names a missing map"),
}


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_bundle_gives_one_clear_error_and_writes_nothing(case, tiny_root: Path, capsys):
    damage, message = BAD_INPUTS[case]
    damage(tiny_root)
    with pytest.raises(ScenarioFormatError, match=message):
        store.read_scenario(tiny_root, "tiny")
    before = _snapshot(tiny_root)
    assert main(["scenarios", str(tiny_root)]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and error[0].startswith("drivee2e: error: ")
    assert "tiny" in error[0]
    assert _snapshot(tiny_root) == before


def test_scenarios_on_a_folder_without_data_fails_clearly(tmp_path: Path, capsys):
    assert main(["scenarios", str(tmp_path)]) == 2
    assert "no scenarios/ folder" in capsys.readouterr().err


def test_written_files_and_bundles_take_the_umask(tmp_path: Path) -> None:
    """Atomic writes go through mkstemp/mkdtemp (0600/0700); what they leave must be readable
    by others on a shared data root as an ordinary write would be."""
    import os
    import stat

    from drivee2e_data import store

    previous = os.umask(0o022)
    try:
        store.write_bytes_atomic(tmp_path / "index.parquet", b"x")
        with store._atomic_folder(tmp_path / "bundle") as folder:
            (folder / "meta.json").write_text("{}")
    finally:
        os.umask(previous)
    assert stat.S_IMODE((tmp_path / "index.parquet").stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "bundle").stat().st_mode) == 0o755


def test_columns_read_from_their_buffers_match_pyarrows_own_conversion():
    """`store.column_values` reads fixed-width and boolean columns from their buffers (pyarrow's
    `to_numpy` imports pandas where it is installed): the same values, also for a column made of
    several chunks and for a slice that starts inside a byte of booleans."""
    import pyarrow as pa

    from drivee2e_data.store import column_values

    flags = pa.chunked_array([[True, False, True], [False, False, True, True, False, True]])
    for column, dtype in (
        (flags, np.bool_),
        (pa.chunked_array([pa.array([True, False, True, True, False, False, True]).slice(3)]),
         np.bool_),
        (pa.chunked_array([[1, 2, 3], [4]], pa.int64()), np.int64),
        (pa.chunked_array([pa.array([0.5, -1.25, 3.0, 7.5], pa.float64()).slice(1, 2)]),
         np.float64),
        (pa.chunked_array([[0, 255, 3]], pa.uint8()), np.uint8),
    ):  # fmt: skip
        values = column_values(column)
        np.testing.assert_array_equal(values, np.asarray(column.to_pylist()))
        assert values.dtype == dtype
