"""Dataset-level jobs on a data root: synthesise a set of clips, summarise what a root holds.

Each job is resumable: finished bundles are atomic folders, and a rerun with the same inputs
skips them instead of redoing them.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from drivee2e_data import store
from drivee2e_data.scenario import AgentClass, Scenario
from drivee2e_data.sources import synthetic


@dataclass(frozen=True)
class SynthReport:
    written: list[str]
    skipped: list[str]
    maps: list[str]


def _finished_synthetic(root: Path, scenario_id: str, seed: int) -> bool:
    """A bundle from an earlier run with the same seed and generator version is already done."""
    meta_file = store.scenario_dir(root, scenario_id) / "meta.json"
    if not meta_file.is_file():
        return False
    try:
        metadata = json.loads(meta_file.read_text(encoding="utf-8")).get("metadata", {})
    except (json.JSONDecodeError, UnicodeDecodeError):
        return False
    return (
        metadata.get("seed") == seed
        and metadata.get("generator_version") == synthetic.GENERATOR_VERSION
    )


def synthesize(
    root: Path,
    clips: int,
    seed: int,
    intersections: int | None = None,
    on_clip: Callable[[str, bool], None] | None = None,
) -> SynthReport:
    """Write `clips` synthetic scenarios and their maps under `root`; `on_clip(id, skipped)`."""
    if clips < 1:
        raise ValueError(f"clips must be at least 1, got {clips}")
    count = intersections or synthetic.default_intersections(clips)
    if count < 1:
        raise ValueError(f"intersections must be at least 1, got {count}")
    sites: dict[int, synthetic.Site] = {}
    written, skipped = [], []
    for clip_index in range(clips):
        site_index = clip_index % count
        if site_index not in sites:
            sites[site_index] = synthetic.make_site(seed, site_index)
            store.write_map(root, sites[site_index].intersection_map)
        scenario_id = synthetic.clip_id(seed, clip_index)
        if _finished_synthetic(root, scenario_id, seed):
            skipped.append(scenario_id)
        else:
            scenario = synthetic.generate_clip(sites[site_index], seed, clip_index)
            store.write_scenario(root, scenario)
            written.append(scenario_id)
        if on_clip is not None:
            on_clip(scenario_id, scenario_id in skipped)
    return SynthReport(
        written, skipped, sorted(site.intersection_map.map_id for site in sites.values())
    )


@dataclass(frozen=True)
class ScenarioSummary:
    """One line of `drivee2e scenarios`."""

    scenario_id: str
    map_id: str
    duration_s: float
    agents: dict[AgentClass, int]
    ego_id: str | None
    behavior: str
    weather: str
    time_of_day: str

    @classmethod
    def of(cls, scenario: Scenario) -> ScenarioSummary:
        return cls(
            scenario.scenario_id,
            scenario.map_id,
            scenario.duration_s,
            scenario.class_counts(),
            scenario.ego_id,
            scenario.behavior.sub_scenario.value if scenario.behavior else "-",
            scenario.conditions.weather.value,
            scenario.conditions.time_of_day.value,
        )


def summarize(
    root: Path, on_scenario: Callable[[str], None] | None = None
) -> list[ScenarioSummary]:
    """Read and validate every bundle under `root` (and that its map exists)."""
    summaries = []
    checked_maps: set[str] = set()
    for scenario_id in store.scenario_ids(root):
        scenario = store.read_scenario(root, scenario_id)
        if scenario.map_id not in checked_maps:
            store.read_map(root, scenario.map_id)
            checked_maps.add(scenario.map_id)
        summaries.append(ScenarioSummary.of(scenario))
        if on_scenario is not None:
            on_scenario(scenario_id)
    return summaries
