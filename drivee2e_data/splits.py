"""Train/val/test splits over whole clips: 2:1:1, stratified by behaviour category, spread over
maps and conditions, deterministic given a seed.

Counts are apportioned twice: the whole set gets 2:1:1 by largest remainder, then each
category gets the floor or the ceiling of its own 2:1:1 share such that the categories add up
to the whole set's counts (a controlled rounding, which always exists for a two-way table).
Inside a category, clips sorted by map, weather and time of day are dealt to the splits in
proportion, so every map and condition spreads over the splits as far as its count allows.

A manifest is a CSV with one row per clip: `scenario_id, split, category, sub_scenario, map,
weather, time_of_day`.
"""

from __future__ import annotations

import csv
import hashlib
import io
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from drivee2e_data import store
from drivee2e_data.curation.replay_flags import recorded_flags
from drivee2e_data.errors import DriveE2EError

SPLITS = ("train", "val", "test")
RATIO = (2, 1, 1)
COLUMNS = ("scenario_id", "split", "category", "sub_scenario", "map", "weather", "time_of_day")
SPLITS_FOLDER = "splits"
UNLABELLED = "none"  # the stratum of clips without a behaviour label


class SplitFormatError(DriveE2EError):
    """A split manifest is missing, malformed or names an unknown split."""


@dataclass(frozen=True)
class ClipRow:
    """One clip's line of a manifest."""

    scenario_id: str
    split: str
    category: str
    sub_scenario: str
    map: str
    weather: str
    time_of_day: str


def apportion(total: int, ratio: Sequence[int] = RATIO) -> list[int]:
    """`total` split in `ratio` by largest remainder (ties go to the earlier split)."""
    exact = [total * r / sum(ratio) for r in ratio]
    counts = [int(e) for e in exact]
    order = sorted(range(len(ratio)), key=lambda k: (-(exact[k] - counts[k]), k))
    for k in order[: total - sum(counts)]:
        counts[k] += 1
    return counts


def controlled_rounding(
    sizes: dict[str, int], ratio: Sequence[int] = RATIO
) -> dict[str, list[int]]:
    """Per stratum, counts per split that are each the floor or ceiling of the stratum's exact
    share and add up, over the strata, to `apportion(sum(sizes))`.

    After the floors, each stratum has a few clips left over and each split a few places
    left; a stratum may give at most one of its clips to a split whose exact share it rounded
    down. That is a bipartite flow, solved by augmenting paths (strata in name order, splits by
    largest remainder first, so the result is deterministic)."""
    parts = sum(ratio)
    totals = apportion(sum(sizes.values()), ratio)
    counts = {name: [size * r // parts for r in ratio] for name, size in sizes.items()}
    demand = [totals[k] - sum(c[k] for c in counts.values()) for k in range(len(ratio))]
    options = {
        name: sorted(
            (k for k in range(len(ratio)) if sizes[name] * ratio[k] % parts),
            key=lambda k: (-(sizes[name] * ratio[k] % parts), k),
        )
        for name in sizes
    }
    given: dict[int, list[str]] = {k: [] for k in range(len(ratio))}  # split -> strata giving

    def augment(name: str, visited: set[int], leaving: int | None = None) -> bool:
        """Give one more unit of `name` to a split (moving it off `leaving`), shifting other
        strata's units along a path when the split it wants is full."""
        for k in options[name]:
            if k == leaving or k in visited or name in given[k]:
                continue
            visited.add(k)
            if len(given[k]) < demand[k]:
                given[k].append(name)
                return True
            for other in list(given[k]):
                if augment(other, visited, leaving=k):
                    given[k].remove(other)
                    given[k].append(name)
                    return True
        return False

    for name in sorted(sizes):
        for _ in range(sizes[name] - sum(counts[name])):
            if not augment(name, set()):
                raise AssertionError(f"no controlled rounding for {sizes}")  # cannot happen
    for k, names in given.items():
        for name in names:
            counts[name][k] += 1
    return counts


def _deal(count_per_split: list[int], offset: int) -> list[int]:
    """A sequence of split indices with the given counts, interleaved in proportion (each next
    item goes to the split furthest behind its share); `offset` rotates where it starts."""
    total = sum(count_per_split)
    dealt = [0] * len(count_per_split)
    sequence = []
    for position in range(total):
        step = position + 1
        behind = [
            (count_per_split[k] * step / total - dealt[k], -k)
            for k in range(len(count_per_split))
            if dealt[k] < count_per_split[k]
        ]
        k = -max(behind)[1]
        dealt[k] += 1
        sequence.append(k)
    if total:
        offset %= total
        sequence = sequence[offset:] + sequence[:offset]
    return sequence


def _hash(seed: int, text: str) -> str:
    return hashlib.sha256(f"{seed}:{text}".encode()).hexdigest()


def make_split(clips: list[ClipRow], seed: int = 0) -> list[ClipRow]:
    """Assign each clip (its `split` field is ignored) to train, val or test; sorted by id."""
    ids = [c.scenario_id for c in clips]
    if len(set(ids)) != len(ids):
        duplicate = next(i for i in ids if ids.count(i) > 1)
        raise SplitFormatError(f"clip {duplicate!r} is listed twice")
    strata: dict[str, list[ClipRow]] = {}
    for clip in clips:
        strata.setdefault(clip.category, []).append(clip)
    counts = controlled_rounding({name: len(members) for name, members in strata.items()})
    assigned = []
    for name in sorted(strata):
        members = sorted(
            strata[name],
            key=lambda c: (c.map, c.weather, c.time_of_day, _hash(seed, c.scenario_id)),
        )
        offset = int(_hash(seed, name)[:8], 16)
        for clip, k in zip(members, _deal(counts[name], offset), strict=True):
            assigned.append(_with_split(clip, SPLITS[k]))
    return sorted(assigned, key=lambda c: c.scenario_id)


def _with_split(clip: ClipRow, split: str) -> ClipRow:
    return ClipRow(split=split, **{k: v for k, v in vars(clip).items() if k != "split"})


FLAGGED = "flagged by the expert-replay check"


def clips_of(root: Path, left_out: dict[str, str] | None = None) -> list[ClipRow]:
    """Every clip under `root` as an unassigned manifest row (from meta.json alone). With
    `left_out` (a dict to fill), clips the expert-replay check flagged are left out and
    recorded there with the reason."""
    rows = []
    for scenario_id in store.scenario_ids(root):
        meta = store.read_meta(root, scenario_id)
        if left_out is not None and recorded_flags(meta.get("metadata") or {}):
            left_out[scenario_id] = FLAGGED
            continue
        behavior = meta.get("behavior") or {}
        sub_scenario = behavior.get("sub_scenario", UNLABELLED)
        conditions = meta.get("conditions") or {}
        rows.append(
            ClipRow(
                scenario_id=scenario_id,
                split="",
                category=sub_scenario.split("-")[0] if behavior else UNLABELLED,
                sub_scenario=sub_scenario,
                map=str(meta.get("map_id", "")),
                weather=str(conditions.get("weather", "")),
                time_of_day=str(conditions.get("time_of_day", "")),
            )
        )
    return rows


def split_path(root: Path, name: str) -> Path:
    """Where the split set `name` of a data root lives; a name ending in .csv is a path."""
    if name.endswith(".csv"):
        return Path(name)
    return Path(root) / SPLITS_FOLDER / f"{name}.csv"


def write_manifest(path: Path, rows: list[ClipRow]) -> None:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(COLUMNS)
    for row in rows:
        writer.writerow([getattr(row, column) for column in COLUMNS])
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    store.write_bytes_atomic(Path(path), buffer.getvalue().encode())


def read_manifest(path: Path) -> list[ClipRow]:
    """A manifest's rows; `SplitFormatError` naming the file and line for anything off."""
    path = Path(path)
    if not path.is_file():
        raise SplitFormatError(f"{path}: no such split manifest (make one with drivee2e split)")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as error:
        raise SplitFormatError(f"{path}: not UTF-8 text ({error.reason})") from None
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if header is None or header[:2] != ["scenario_id", "split"]:
        raise SplitFormatError(
            f"{path} line 1: header {header!r}, expected columns starting scenario_id,split"
        )
    rows, seen = [], set()
    for line, cells in enumerate(reader, start=2):
        if not cells:
            continue
        values = dict(zip(header, cells, strict=False))
        scenario_id, split = values.get("scenario_id", ""), values.get("split", "")
        if not scenario_id:
            raise SplitFormatError(f"{path} line {line}: empty scenario_id")
        if split not in SPLITS:
            raise SplitFormatError(
                f"{path} line {line}: split {split!r}, expected one of {', '.join(SPLITS)}"
            )
        if scenario_id in seen:
            raise SplitFormatError(f"{path} line {line}: clip {scenario_id!r} is listed twice")
        seen.add(scenario_id)
        rows.append(
            ClipRow(**{column: values.get(column, "") for column in COLUMNS})  # type: ignore[arg-type]
        )
    return rows


def split_root(
    root: Path, name: str = "default", seed: int = 0, keep_flagged: bool = False
) -> tuple[Path, list[ClipRow], dict[str, str]]:
    """Split the clips of a data root and write `root/splits/<name>.csv`: every clip but those
    the expert-replay check flagged (unless `keep_flagged`). Returns the manifest's path, its
    rows and the clips left out with why."""
    left_out: dict[str, str] = {}
    clips = clips_of(root, None if keep_flagged else left_out)
    if not clips:
        if left_out:
            raise DriveE2EError(
                f"{root}: every clip was flagged by the expert-replay check; --keep-flagged "
                "keeps them"
            )
        raise DriveE2EError(f"{root}: no scenarios to split (expected {root}/scenarios/<id>/)")
    rows = make_split(clips, seed)
    path = split_path(root, name)
    write_manifest(path, rows)
    return path, rows, left_out


def scenario_ids(path: Path, split: str) -> list[str]:
    """The clips of one split of a manifest (or of all of them, `all`), in manifest order."""
    if split not in (*SPLITS, "all"):
        raise SplitFormatError(f"split {split!r}: expected one of {', '.join(SPLITS)} or all")
    return [row.scenario_id for row in read_manifest(path) if split in ("all", row.split)]


def counts_table(rows: list[ClipRow]) -> list[tuple[str, ...]]:
    """Clips per category and split, with a total row: header first."""
    categories = sorted({r.category for r in rows})
    table: list[tuple[str, ...]] = [("category", *SPLITS, "total")]
    for name in [*categories, "all"]:
        members = [r for r in rows if name in ("all", r.category)]
        counts = [sum(r.split == s for r in members) for s in SPLITS]
        table.append((name, *map(str, counts), str(len(members))))
    return table
