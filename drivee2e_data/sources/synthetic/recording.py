"""A long synthetic recording: one intersection's traffic for minutes, with no staged ego, as
drone or infrastructure data would give it. Import-style cutting (`sources.cutting`) then splits
it into clips, one per usable ego or in fixed windows.
"""

from __future__ import annotations

import numpy as np

from drivee2e_data.scenario import Scenario
from drivee2e_data.sources.synthetic import (
    GENERATOR_VERSION,
    SOURCE_NAME,
    Site,
    make_site,
    random_conditions,
    simulated_tracks,
)
from drivee2e_data.sources.synthetic.population import background_pedestrians, background_vehicles
from drivee2e_data.sources.synthetic.staging import WARMUP_S, _pick_victim, first_overlap
from drivee2e_data.sources.synthetic.traffic import STEP_S, TrafficSimulation

MAX_REPAIRS = 200  # agents left out, at most, to keep every box apart over the recording


def recording_id(seed: int, site_index: int) -> str:
    return f"synth_s{seed}_rec{site_index:02d}"


def generate_recording(seed: int, site_index: int, duration_s: float) -> tuple[Site, Scenario]:
    """`duration_s` seconds of the traffic at site `site_index` after a warm-up, no two boxes
    overlapping (the later of a clashing pair is left out, as in staging)."""
    if duration_s < 10.0:
        raise ValueError(f"a recording must last at least 10 s, got {duration_s}")
    site = make_site(seed, site_index)
    rng = np.random.default_rng([seed, 3, site_index])
    horizon = WARMUP_S + duration_s
    vehicles = background_vehicles(site.layout, horizon, rng)
    pedestrians = background_pedestrians(site.layout, horizon, rng)
    first, last = round(WARMUP_S / STEP_S), round(horizon / STEP_S)
    removed = 0
    for _ in range(MAX_REPAIRS):
        result = TrafficSimulation(site.network, site.plan, vehicles, pedestrians, horizon).run()
        clash = first_overlap(result, vehicles, pedestrians, first, last)
        if clash is None:
            break
        victim = _pick_victim(clash, result, vehicles, pedestrians, protected=set())
        vehicles = [v for v in vehicles if v.agent_id != victim]
        pedestrians = [p for p in pedestrians if p.agent_id != victim]
        removed += 1
    else:
        raise RuntimeError(f"{recording_id(seed, site_index)}: boxes still overlap after repairs")
    conditions = random_conditions(rng, site.intersection_map)
    window = slice(first, last + 1)
    t0_ns = int(conditions.start_time_utc.timestamp()) * 1_000_000_000
    tracks, signals = simulated_tracks(site, result, vehicles, pedestrians, window)
    scenario = Scenario(
        scenario_id=recording_id(seed, site_index),
        map_id=site.intersection_map.map_id,
        source=SOURCE_NAME,
        t_ns=t0_ns + 100_000_000 * np.arange(last - first + 1, dtype=np.int64),
        tracks=tracks,
        signals=signals,
        conditions=conditions,
        metadata={
            "generator": SOURCE_NAME,
            "generator_version": GENERATOR_VERSION,
            "seed": seed,
            "kind": "recording",
            "recording_seconds": duration_s,
            "agents_removed_for_overlap": removed,
        },
    )
    return site, scenario
