"""Splits: 2:1:1 over whole clips, stratified by category, deterministic; manifests."""

from __future__ import annotations

import random
from pathlib import Path

import pytest

from drivee2e_data import splits
from drivee2e_data.cli import main


def _clips(sizes: dict[str, int], maps: int = 3) -> list[splits.ClipRow]:
    rows = []
    for category, size in sizes.items():
        for k in range(size):
            rows.append(
                splits.ClipRow(
                    scenario_id=f"{category}_{k:03d}",
                    split="",
                    category=category,
                    sub_scenario=category,
                    map=f"map{k % maps}",
                    weather="clear" if k % 2 else "rain",
                    time_of_day="noon",
                )
            )
    return rows


def _counts(rows: list[splits.ClipRow], category: str | None = None) -> list[int]:
    chosen = [r for r in rows if category in (None, r.category)]
    return [sum(r.split == s for r in chosen) for s in splits.SPLITS]


def test_apportion_is_two_one_one_within_one_clip() -> None:
    assert splits.apportion(8) == [4, 2, 2]
    assert splits.apportion(9) == [5, 2, 2]
    assert splits.apportion(10) == [5, 3, 2]
    assert splits.apportion(1) == [1, 0, 0]
    for total in range(0, 60):
        counts = splits.apportion(total)
        assert sum(counts) == total
        assert all(abs(c - total * r / 4) < 1 for c, r in zip(counts, splits.RATIO, strict=True))


def test_controlled_rounding_keeps_every_cell_a_floor_or_ceiling() -> None:
    rng = random.Random(7)
    for _ in range(300):
        sizes = {f"c{k}": rng.randint(0, 13) for k in range(rng.randint(1, 9))}
        counts = splits.controlled_rounding(sizes)
        totals = [sum(c[k] for c in counts.values()) for k in range(3)]
        assert totals == splits.apportion(sum(sizes.values())), sizes
        for name, size in sizes.items():
            assert sum(counts[name]) == size
            for k, ratio in enumerate(splits.RATIO):
                assert abs(counts[name][k] - size * ratio / 4) < 1, (sizes, name, counts[name])


def test_split_is_stratified_disjoint_and_deterministic() -> None:
    clips = _clips(
        {"STR": 40, "LFT": 23, "RT": 17, "IPC": 9, "COV": 6, "YLW": 3, "UT": 2, "STP": 1}
    )
    rows = splits.make_split(clips, seed=0)
    assert sorted(r.scenario_id for r in rows) == sorted(c.scenario_id for c in clips)
    assert len({r.scenario_id for r in rows}) == len(rows)  # no clip in two splits
    assert _counts(rows) == splits.apportion(len(clips))
    for category in {c.category for c in clips}:
        size = sum(c.category == category for c in clips)
        for count, ratio in zip(_counts(rows, category), splits.RATIO, strict=True):
            assert abs(count - size * ratio / 4) < 1
    assert splits.make_split(clips, seed=0) == rows
    assert splits.make_split(list(reversed(clips)), seed=0) == rows  # order of input is moot
    assert splits.make_split(clips, seed=1) != rows


def test_split_spreads_maps_over_splits() -> None:
    rows = splits.make_split(_clips({"STR": 48}, maps=3), seed=3)
    for map_id in ("map0", "map1", "map2"):
        assert _counts([r for r in rows if r.map == map_id]) == [8, 4, 4]


def test_manifest_round_trip_and_cli(synthetic_root: Path, tmp_path: Path, capsys) -> None:
    assert main(["split", str(synthetic_root), "--name", "check", "--seed", "2"]) == 0
    path = synthetic_root / "splits" / "check.csv"
    rows = splits.read_manifest(path)
    assert len(rows) == 12
    assert _counts(rows) == [6, 3, 3]
    assert path.read_text().splitlines()[0] == ",".join(splits.COLUMNS)
    assert "wrote" in capsys.readouterr().out
    copy = tmp_path / "copy.csv"
    splits.write_manifest(copy, rows)
    assert copy.read_bytes() == path.read_bytes()
    assert splits.scenario_ids(path, "val") == [r.scenario_id for r in rows if r.split == "val"]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("scenario_id,split\na,train\na,val\n", "line 3: clip 'a' is listed twice"),
        ("scenario_id,split\na,training\n", "line 2: split 'training', expected one of"),
        ("id,split\na,train\n", "line 1: header"),
        ("scenario_id,split\n,train\n", "line 2: empty scenario_id"),
    ],
)
def test_bad_manifest_names_file_and_line(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(splits.SplitFormatError, match=message) as caught:
        splits.read_manifest(path)
    assert str(path) in str(caught.value)


def test_missing_manifest_says_how_to_make_one(tmp_path: Path) -> None:
    with pytest.raises(splits.SplitFormatError, match="drivee2e split"):
        splits.read_manifest(tmp_path / "nope.csv")
