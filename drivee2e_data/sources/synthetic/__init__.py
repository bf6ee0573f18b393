"""Synthetic intersections and traffic: the embedded default source, deterministic from a seed.

`generate(clips, seed)` yields (map, scenario) pairs: procedural 3- and 4-way intersections with
fixed-time signals, IDM traffic of all eight classes, pedestrians on their phase, and an ego
staged to show one of the 14 sub-scenarios, cycling so that every category occurs.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

import numpy as np

from drivee2e_data.geometry import polyline_arclength, resample_polyline
from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.scenario import (
    FRAME_PERIOD_NS,
    AgentClass,
    BehaviorLabel,
    Conditions,
    Route,
    Scenario,
    SignalTimeline,
    SubScenario,
    Track,
    Weather,
)
from drivee2e_data.sources.synthetic.layout import Layout, generate_layout
from drivee2e_data.sources.synthetic.paths import PathNetwork, build_network
from drivee2e_data.sources.synthetic.signals import SignalPlan, make_plan
from drivee2e_data.sources.synthetic.staging import StagedClip, StagingError, stage_clip
from drivee2e_data.sources.synthetic.traffic import PedestrianSpec, SimResult, VehicleSpec
from drivee2e_data.sun import time_of_day_of

SOURCE_NAME = "synthetic"
GENERATOR_VERSION = 3  # 3: kerbs around the turns, U-turns that fit, the expert's margin in staging
UTC_OFFSET_H = 8  # the synthetic sites sit near Beijing (UTC+8), like V2X-Seq's
# Targets in the order clips take them: the eight categories come first, then the other six.
TARGET_ORDER = (
    SubScenario.STR,
    SubScenario.LFT,
    SubScenario.RT,
    SubScenario.STP,
    SubScenario.YLW_STR,
    SubScenario.UT_N,
    SubScenario.IPC_RT,
    SubScenario.COV_LFT,
    SubScenario.YLW_LFT,
    SubScenario.IPC_LFT,
    SubScenario.COV_STR,
    SubScenario.UT_AN,
    SubScenario.IPC_STR,
    SubScenario.COV_RT,
)


@dataclass(frozen=True)
class Site:
    """One generated intersection and what its traffic needs."""

    layout: Layout
    network: PathNetwork
    plan: SignalPlan

    @property
    def intersection_map(self) -> IntersectionMap:
        return self.layout.intersection_map


def default_intersections(clips: int) -> int:
    return max(1, min(4, clips))


def make_site(seed: int, index: int) -> Site:
    rng = np.random.default_rng([seed, 1, index])
    layout = generate_layout(f"synth_s{seed}_i{index:02d}", rng)
    return Site(layout, build_network(layout), make_plan(layout, rng))


def clip_id(seed: int, clip_index: int) -> str:
    return f"synth_s{seed}_c{clip_index:04d}"


def generate_clip(site: Site, seed: int, clip_index: int) -> Scenario:
    """Clip `clip_index` of the dataset with `seed`, staged on `site`."""
    rng = np.random.default_rng([seed, 2, clip_index])
    first = clip_index % len(TARGET_ORDER)
    # a site may offer no way to stage a target (no conflicting left turn on some layouts):
    # the clip then takes the next target in the order, deterministically
    for shift in range(len(TARGET_ORDER)):
        target = TARGET_ORDER[(first + shift) % len(TARGET_ORDER)]
        try:
            staged = stage_clip(site.layout, site.network, site.plan, target, rng)
            break
        except StagingError:
            continue
    else:
        raise StagingError(f"could not stage any target on {site.intersection_map.map_id}")
    conditions = random_conditions(rng, site.intersection_map)
    return _scenario(clip_id(seed, clip_index), site, staged, conditions, seed)


def generate(
    clips: int, seed: int, intersections: int | None = None
) -> Iterator[tuple[IntersectionMap, Scenario]]:
    """(map, scenario) for each of `clips` clips, spread round-robin over the intersections."""
    count = intersections or default_intersections(clips)
    sites: dict[int, Site] = {}
    for clip_index in range(clips):
        site_index = clip_index % count
        if site_index not in sites:
            sites[site_index] = make_site(seed, site_index)
        site = sites[site_index]
        yield site.intersection_map, generate_clip(site, seed, clip_index)


def random_conditions(rng: np.random.Generator, intersection_map: IntersectionMap) -> Conditions:
    weather = list(Weather)[int(rng.integers(len(Weather)))]
    local_hour = float(rng.choice([6.0, 9.0, 12.5, 15.5, 18.3, 21.5]) + rng.uniform(-0.8, 0.8))
    day = datetime(2026, 4, 1, tzinfo=timezone.utc) + timedelta(days=int(rng.integers(0, 180)))
    start = day + timedelta(hours=local_hour - UTC_OFFSET_H)
    start = start.replace(microsecond=0)
    return Conditions(weather, time_of_day_of(start, intersection_map.origin), start)


def simulated_tracks(
    site: Site,
    result: SimResult,
    vehicles: list[VehicleSpec],
    pedestrians: list[PedestrianSpec],
    window: slice,
) -> tuple[tuple[Track, ...], tuple[SignalTimeline, ...]]:
    """The agents seen in `window` of a simulation as tracks (ids by order of appearance), and
    the signal timelines over it."""
    vehicle_count = len(vehicles)
    names = _track_names(result, vehicle_count, window)
    tracks = []
    for row in sorted(names, key=lambda r: names[r]):
        agent_id = names[row]
        valid = result.valid[row, window]
        if row < vehicle_count:
            spec = vehicles[row]
            agent_class, size = spec.agent_class, (spec.length_m, spec.width_m, spec.height_m)
            path = site.network.paths[spec.movement_id]
            metadata = {
                "lanes": ",".join(lane for lane, _, _ in path.lanes),
                "movement": path.movement.turn.value,
                "signal": path.movement.signal_id,
                "runs_yellow": str(spec.runs_yellow).lower(),
            }
        else:
            pedestrian = pedestrians[row - vehicle_count]
            agent_class, size = AgentClass.PEDESTRIAN, pedestrian.size_m
            metadata = {
                "jaywalks": str(pedestrian.jaywalks).lower(),
                "crossing": pedestrian.crossing.crossing_id,
            }
        yaw = result.yaw_rad[row, window]
        speed = result.speed_mps[row, window]
        tracks.append(
            Track(
                track_id=agent_id,
                agent_class=agent_class,
                x_m=np.where(valid, result.x_m[row, window], np.nan),
                y_m=np.where(valid, result.y_m[row, window], np.nan),
                z_m=np.where(valid, 0.5 * size[2], np.nan),
                yaw_rad=np.where(valid, yaw, np.nan),
                length_m=np.where(valid, size[0], np.nan),
                width_m=np.where(valid, size[1], np.nan),
                height_m=np.where(valid, size[2], np.nan),
                vx_mps=np.where(valid, speed * np.cos(yaw), np.nan),
                vy_mps=np.where(valid, speed * np.sin(yaw), np.nan),
                valid=valid,
                metadata=metadata,
            )
        )
    signals = tuple(
        SignalTimeline(signal_id, states[window], origin="synthetic")
        for signal_id, states in result.signal_states.items()
    )
    return tuple(tracks), signals


def _scenario(
    scenario_id: str, site: Site, staged: StagedClip, conditions: Conditions, seed: int
) -> Scenario:
    result = staged.result
    window = slice(staged.first_step, staged.last_step + 1)
    frames = staged.last_step - staged.first_step + 1
    t0_ns = int(conditions.start_time_utc.timestamp()) * 1_000_000_000
    tracks, signals = simulated_tracks(site, result, staged.vehicles, staged.pedestrians, window)
    names = _track_names(result, len(staged.vehicles), window)
    ego_id = names[staged.ego_row]
    ego_path = site.network.paths[staged.vehicles[staged.ego_row].movement_id]
    ego_xy = np.stack([result.x_m[staged.ego_row, window], result.y_m[staged.ego_row, window]], -1)
    return Scenario(
        scenario_id=scenario_id,
        map_id=site.intersection_map.map_id,
        source=SOURCE_NAME,
        t_ns=t0_ns + FRAME_PERIOD_NS * np.arange(frames, dtype=np.int64),
        tracks=tuple(tracks),
        signals=signals,
        conditions=conditions,
        ego_id=ego_id,
        route=Route(tuple(lane for lane, _, _ in ego_path.lanes), _route_waypoints(ego_xy)),
        behavior=BehaviorLabel(staged.observed, "staged"),
        metadata={
            "generator": SOURCE_NAME,
            "generator_version": GENERATOR_VERSION,
            "seed": seed,
            "target_sub_scenario": staged.target.value,
            "staged_as_targeted": staged.observed == staged.target,
            "agents_removed_for_overlap": staged.removed_agents,
            "clip_start_sim_s": round(staged.first_step * 0.1, 1),
        },
    )


def _track_names(result: SimResult, vehicle_count: int, window: slice) -> dict[int, str]:
    """Track ids for the sim rows seen in the clip: 'v0000'.. and 'p0000'.. in order of appearance,
    so nothing in an id tells which vehicle is the ego."""
    valid = result.valid[:, window]
    seen = [row for row in range(valid.shape[0]) if valid[row].any()]
    order = sorted(seen, key=lambda row: (int(np.argmax(valid[row])), result.agent_ids[row]))
    names: dict[int, str] = {}
    for row in order:
        prefix = "v" if row < vehicle_count else "p"
        names[row] = f"{prefix}{sum(1 for n in names.values() if n[0] == prefix):04d}"
    return names


def _route_waypoints(xy_m: np.ndarray) -> np.ndarray:
    """The ego's driven path resampled every 1 m (a single point repeated if it never moved)."""
    step = np.linalg.norm(np.diff(xy_m, axis=0), axis=1)
    moving = np.concatenate([[True], step > 1e-6])
    points = xy_m[moving]
    if len(points) < 2 or polyline_arclength(points)[-1] < 1.0:
        return np.stack([xy_m[0], xy_m[-1] + np.array([1e-3, 0.0])])
    return resample_polyline(points, 1.0)
