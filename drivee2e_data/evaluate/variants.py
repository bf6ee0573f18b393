"""Occlusion variants on disk: `DATA/variants/<variant>.json` lists, per clip, the agents the
variant removes (`drivee2e curate DATA --occlusion vehicle|all` writes it from the collected
logs; `drivee2e evaluate --variant` reads it)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from drivee2e_data import store
from drivee2e_data.curation.occlusion import Variant, unseen_agents
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader

FOLDER = "variants"


def variant_path(root: Path, variant: Variant) -> Path:
    return Path(root) / FOLDER / f"{variant.value}.json"


def seen_track_ids(log: LogReader) -> set[str]:
    """Agents annotated with a nonzero visibility in some frame of the log."""
    seen: set[str] = set()
    for _, _, _, decoded in log.decoded_messages([topics.OBJECTS]):
        seen.update(o.instance_id for o in decoded.objects if o.visibility > 0)
    return seen


def write_variant(
    root: Path, variant: Variant, on_clip: Callable[[str], None] | None = None
) -> tuple[Path, dict[str, list[str]]]:
    """The variant's removed agents for every clip with a log; written atomically."""
    removed: dict[str, list[str]] = {}
    for scenario_id in store.scenario_ids(root):
        log_file = Path(root) / "logs" / f"{scenario_id}.mcap"
        if not log_file.is_file():
            continue
        scenario = store.read_scenario(root, scenario_id)
        with LogReader(log_file) as log:
            removed[scenario_id] = unseen_agents(scenario, seen_track_ids(log), log.frames, variant)
        if on_clip is not None:
            on_clip(scenario_id)
    if not removed:
        raise DriveE2EError(f"{root}: no logs under logs/; run drivee2e collect first")
    path = variant_path(root, variant)
    document = {"variant": variant.value, "removed": removed}
    store.write_bytes_atomic(path, json.dumps(document, indent=1, sort_keys=True).encode())
    return path, removed


def read_variant(root: Path, variant: Variant) -> dict[str, frozenset[str]]:
    """Removed agents per clip (empty for `complete`)."""
    if variant is Variant.COMPLETE:
        return {}
    path = variant_path(root, variant)
    flag = "vehicle" if variant is Variant.OCC_VEHICLE else "all"
    if not path.is_file():
        raise DriveE2EError(f"{path}: missing; run drivee2e curate {root} --occlusion {flag}")
    try:
        document = json.loads(path.read_text())
        return {sid: frozenset(ids) for sid, ids in document["removed"].items()}
    except (ValueError, KeyError, TypeError, AttributeError) as error:
        raise DriveE2EError(
            f"{path}: expected {{'variant': ..., 'removed': {{clip: [track ids]}}}} ({error})"
        ) from None
