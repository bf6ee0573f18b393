"""Which clip a closed-loop pool worker runs next. Each task claims its clip when it starts:
the longest left on the map its worker's world already shows (a worker keeps its world for the
next clip on that map: a replay takes a few tenths of a second where a new twin takes one or
two), else the longest left, so the last worker to finish waits least. A claim is a file made
exclusively in a folder the run's tasks share: no two tasks take the same clip, whichever
worker runs them and in whatever order; as many tasks as clips claim every clip once, so once
every clip is claimed no task is left to start (`all_claimed`)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from drivee2e_data import store
from drivee2e_data.errors import DriveE2EError

# (scenario id, map id or "" where the bundle cannot be read) of each clip, longest first
ClipOrder = tuple[tuple[str, str], ...]


def clip_order(root: Path, scenario_ids: Sequence[str]) -> ClipOrder:
    """The clips of `scenario_ids` with their maps, longest (in frames) first; a bundle whose
    meta cannot be read sorts last, with no map (its episode will say why)."""
    rows = []
    for scenario_id in scenario_ids:
        try:
            meta = store.read_meta(root, scenario_id)
            meta_file = store.scenario_dir(root, scenario_id) / "meta.json"
            frames = store.meta_timeline(meta, meta_file)[1]
            rows.append((scenario_id, str(meta.get("map_id", "")), frames))
        except DriveE2EError:
            rows.append((scenario_id, "", 0))
    rows.sort(key=lambda row: -row[2])  # stable: ties keep the given order
    return tuple((scenario_id, map_id) for scenario_id, map_id, _ in rows)


def claim(folder: Path, order: ClipOrder, map_id: str | None) -> str:
    """The first clip of `order` on `map_id` (the map the worker's world shows; None: none)
    that no task has claimed yet, else the first unclaimed of all: claimed by making
    `folder`/<scenario id> exclusively."""
    preferred = [s for s, m in order if map_id and m == map_id]
    for scenario_id in (*preferred, *(s for s, m in order if not (map_id and m == map_id))):
        try:
            os.close(os.open(folder / scenario_id, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            continue
        return scenario_id
    raise DriveE2EError(f"{folder}: every one of the {len(order)} clips is claimed already")


def all_claimed(folder: Path, order: ClipOrder) -> bool:
    """Whether every clip of `order` has been claimed in `folder`: no task of the run is left
    to start, so a worker whose episode ends then has none to come."""
    return len(os.listdir(folder)) >= len(order)
