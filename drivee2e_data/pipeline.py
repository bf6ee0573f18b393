"""The pipeline's stages on a data root: synthesise a set of clips, import, curate, summarise.

Each job is resumable: finished bundles are atomic folders, and a rerun with the same inputs
skips them instead of redoing them.
"""

from __future__ import annotations

import dataclasses
import json
from collections import Counter
from collections.abc import Callable, Collection, Iterable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from drivee2e_data import store
from drivee2e_data.curation.replay_flags import Flag
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.scenario import AgentClass, BehaviorCategory, BehaviorLabel, Scenario
from drivee2e_data.sources import synthetic
from drivee2e_data.sources.common import ImportReport
from drivee2e_data.sources.cutting import CUT_MODES, CutReport, cut_clips, cut_ego_clips
from drivee2e_data.sources.ground import GroundPlane, level


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
    workers: int = 1,
    only: Collection[str] | None = None,
) -> SynthReport:
    """Write `clips` synthetic scenarios and their maps under `root`; `on_clip(id, skipped)`.

    With `workers > 1` the clips are generated in that many processes; every clip depends only
    on (seed, clip index), so the files are the same whatever the number of workers, and with
    `only` (clip ids of this set) just those clips are written, the same as in the whole set.
    """
    if clips < 1:
        raise ValueError(f"clips must be at least 1, got {clips}")
    count = intersections or synthetic.default_intersections(clips)
    if count < 1:
        raise ValueError(f"intersections must be at least 1, got {count}")
    wanted = None
    if only is not None:
        ids = {synthetic.clip_id(seed, index): index for index in range(clips)}
        unknown = sorted(set(only) - set(ids))
        if unknown:
            raise DriveE2EError(
                f"--only: clip {unknown[0]!r} is not one of the {clips} clips of seed {seed} "
                f"({synthetic.clip_id(seed, 0)} ... {synthetic.clip_id(seed, clips - 1)})"
            )
        wanted = {ids[scenario_id] for scenario_id in only}
    maps = []
    for site_index in range(min(count, clips)):
        site = _synthetic_site(seed, site_index)
        store.write_map(root, site.intersection_map)
        maps.append(site.intersection_map.map_id)
    jobs = [
        (Path(root), seed, clip_index % count, clip_index)
        for clip_index in range(clips)
        if wanted is None or clip_index in wanted
    ]
    written, skipped = [], []
    if workers <= 1:
        outcomes: Iterable[tuple[str, bool]] = (_synthesize_clip(*job) for job in jobs)
        for scenario_id, was_skipped in outcomes:
            (skipped if was_skipped else written).append(scenario_id)
            if on_clip is not None:
                on_clip(scenario_id, was_skipped)
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = [pool.submit(_synthesize_clip, *job) for job in jobs]
            for future in as_completed(futures):
                scenario_id, was_skipped = future.result()
                (skipped if was_skipped else written).append(scenario_id)
                if on_clip is not None:
                    on_clip(scenario_id, was_skipped)
    return SynthReport(sorted(written), sorted(skipped), sorted(maps))


_sites: dict[tuple[int, int], synthetic.Site] = {}  # this process's sites, by (seed, index)


def _synthetic_site(seed: int, site_index: int) -> synthetic.Site:
    if (seed, site_index) not in _sites:
        _sites[(seed, site_index)] = synthetic.make_site(seed, site_index)
    return _sites[(seed, site_index)]


def _synthesize_clip(root: Path, seed: int, site_index: int, clip_index: int) -> tuple[str, bool]:
    """One clip written (or found finished): its id and whether it was skipped."""
    scenario_id = synthetic.clip_id(seed, clip_index)
    if _finished_synthetic(root, scenario_id, seed):
        return scenario_id, True
    scenario = synthetic.generate_clip(_synthetic_site(seed, site_index), seed, clip_index)
    store.write_scenario(root, scenario)
    return scenario_id, False


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


IMPORT_KINDS = (
    "drivee2e",
    "v2x-seq",
    "av2",
    "commonroad",
    "sind",
    "interaction",
    "lanelet2",
    "scenarionet",
)


@dataclass(frozen=True)
class ImportSummary:
    maps: list[str]
    scenarios: list[str]
    report: ImportReport
    cuts: dict[str, CutReport] = dataclasses.field(default_factory=dict)  # recording -> its cut
    failures: dict[str, str] = dataclasses.field(default_factory=dict)  # source file -> error
    # map -> the ground removed from it (`sources.ground`)
    grounds: dict[str, GroundPlane] = dataclasses.field(default_factory=dict)
    egoless: int = 0  # clips with no motor vehicle (no ego possible), not written unless kept


def _one(paths: list[Path], what: str, where: Path) -> Path:
    if len(paths) != 1:
        raise DriveE2EError(f"{where}: expected exactly one {what}, found {len(paths)}")
    return paths[0]


ImportJob = Callable[[], tuple[IntersectionMap, Scenario | None, ImportReport]]


def _jobs(kind: str, source: Path) -> list[tuple[str, ImportJob]]:
    """One job per clip (or recording) the source holds, named after its file: each parses in
    memory and fails on its own."""
    from drivee2e_data.sources import (
        argoverse2,
        commonroad,
        drivee2e_clip,
        interaction,
        lanelet2,
        scenarionet,
        sind,
        v2x_seq,
    )

    if not source.exists():
        raise DriveE2EError(f"{source}: no such file or folder")
    if kind == "lanelet2":

        def map_job():
            report = ImportReport()
            return lanelet2.read_map(source, f"lanelet2_{source.stem}", report=report), None, report

        return [(str(source), map_job)]
    if kind == "av2":
        if (source / "annotations.feather").exists():
            return [(str(source), partial(_call, argoverse2.import_sensor_log, source))]
        return [(str(source), partial(_call, argoverse2.import_forecasting, source))]
    if kind == "sind":

        def sind_job():
            result = sind.import_sind(source)
            return result.intersection_map, result.recording, result.report

        return [(str(source), sind_job)]
    if kind == "commonroad":
        files = [source] if source.is_file() else sorted(source.glob("*.xml"))
        return [(str(f), partial(_call, commonroad.import_commonroad, f)) for f in files]
    if kind == "scenarionet":
        files = scenarionet.scenario_files(source)
        return [(str(f), partial(_call, scenarionet.import_scenario, f)) for f in files]
    if kind == "interaction":
        return [
            (
                str(csvs[0].parent / name),
                partial(_call, interaction.import_interaction, csvs, osm, name),
            )
            for name, csvs, osm in interaction.recordings(source)
        ]
    if kind not in ("v2x-seq", "drivee2e"):
        raise DriveE2EError(
            f"unknown import kind {kind!r}; expected one of {', '.join(IMPORT_KINDS)}"
        )
    hdmap = _one(sorted(source.rglob("hdmap*.json")), "hdmap*.json map", source)
    if kind == "v2x-seq":
        folder = source / "trajectories" if (source / "trajectories").is_dir() else source
        jobs = []
        for csv_path in sorted(folder.glob("*.csv")):
            lights = source / "traffic_light" / csv_path.name
            lights_file = lights if lights.is_file() else None
            job = partial(_call, v2x_seq.import_v2x_seq, csv_path, lights_file, hdmap)
            jobs.append((str(csv_path), job))
        return jobs

    def clip_job(route: Path):
        csv_id = str(drivee2e_clip.read_route(route)["scenario_csv_id"])
        clip = _one(sorted(source.rglob(f"{csv_id}.csv")), f"clip CSV {csv_id}.csv", source)
        return _call(drivee2e_clip.import_clip, clip, route, hdmap)

    return [(str(route), partial(clip_job, route)) for route in sorted(source.rglob("*.xml"))]


def _call(function: Callable, *arguments) -> tuple[IntersectionMap, Scenario | None, ImportReport]:
    result = function(*arguments)
    return result.intersection_map, result.scenario, result.report


def _load(
    kind: str, source: Path
) -> tuple[list[IntersectionMap], list[Scenario], ImportReport, dict[str, str]]:
    """Every job parsed in memory, so bad input writes nothing: maps, scenarios, the merged
    report, and the failures (source -> error) of a folder's clips that failed on their own. A
    source of one clip, or a folder whose every clip failed, raises its (first) error."""
    jobs = _jobs(kind, source)
    if not jobs:
        raise DriveE2EError(f"{source}: nothing to import for {kind}")
    maps: dict[str, IntersectionMap] = {}
    scenarios: list[Scenario] = []
    report, failures = ImportReport(), {}
    for name, job in jobs:
        try:
            intersection_map, scenario, job_report = job()
        except DriveE2EError as error:
            if len(jobs) == 1:
                raise
            failures[name] = str(error)
            continue
        maps[intersection_map.map_id] = intersection_map
        if scenario is not None:
            scenarios.append(scenario)
        _merge(report, job_report)
    if len(failures) == len(jobs):
        first = next(iter(failures.values()))
        raise DriveE2EError(f"all {len(jobs)} clips failed to import; the first: {first}")
    return list(maps.values()), scenarios, report, failures


def _merge(into: ImportReport, other: ImportReport) -> None:
    into.kept.update(other.kept)
    into.static.update(other.static)
    for table_into, table_other in ((into.mapped, other.mapped), (into.dropped, other.dropped)):
        for name, (label, count) in table_other.items():
            table_into[name] = (label, table_into.get(name, (label, 0))[1] + count)
    into.warnings.extend(other.warnings)


def split_recording(
    scenario: Scenario, intersection_map: IntersectionMap, clip_s: float, cut: str = "ego"
) -> tuple[list[Scenario], CutReport | None]:
    """A scenario longer than 1.5 clips cut into clips, ego-first (`cut="ego"`, falling back to
    fixed windows where no vehicle passes through a junction) or in fixed `clip_s` windows; a
    shorter one as it is (report None)."""
    if cut not in CUT_MODES:
        raise DriveE2EError(f"unknown cut {cut!r}; expected one of {', '.join(CUT_MODES)}")
    if scenario.duration_s <= 1.5 * clip_s:
        return [scenario], None
    if cut == "ego":
        clips, report = cut_ego_clips(scenario, intersection_map)
        if clips:
            return clips, report
        report.fallback = report.fallback or "no vehicle passes through the junction"
    else:
        report = CutReport(fallback="asked for (--cut windows)")
    candidates = [t.track_id for t in scenario.tracks if t.agent_class.is_motor_vehicle]
    return cut_clips(scenario, clip_s, candidates), report


def import_source(
    root: Path,
    kind: str,
    source: Path,
    clip_s: float = 20.0,
    on_scenario: Callable[[str], None] | None = None,
    cut: str = "ego",
    keep_egoless: bool = False,
) -> ImportSummary:
    """Import real data of `kind` from `source` into `root`, the road on the twin's ground
    (`sources.ground.level`); recordings longer than 1.5 clips are cut into clips
    (`split_recording`). Clips without a motor vehicle (nothing could be their ego: SinD's
    shared samples hold pedestrians only) are counted and not written unless `keep_egoless`."""
    maps, scenarios, report, failures = _load(kind, Path(source))
    maps, scenarios, grounds = level(maps, scenarios)
    written, cuts, egoless = [], {}, 0
    by_id = {m.map_id: m for m in maps}
    for intersection_map in maps:
        store.write_map(root, intersection_map)
    for scenario in scenarios:
        pieces, cut_report = split_recording(scenario, by_id[scenario.map_id], clip_s, cut)
        if cut_report is not None:
            cuts[scenario.scenario_id] = cut_report
        for piece in pieces:
            if not keep_egoless and not _can_have_ego(piece):
                egoless += 1
                continue
            store.write_scenario(root, piece)
            written.append(piece.scenario_id)
            if on_scenario is not None:
                on_scenario(piece.scenario_id)
    return ImportSummary([m.map_id for m in maps], written, report, cuts, failures, grounds,
                         egoless)  # fmt: skip


def _can_have_ego(scenario: Scenario) -> bool:
    """Whether a clip holds a motor vehicle (the only class an ego can be)."""
    return any(t.agent_class.is_motor_vehicle and t.valid.any() for t in scenario.tracks)


def synthesize_recording(
    root: Path, seed: int, seconds: float, clip_s: float = 20.0, cut: str = "ego"
) -> tuple[list[str], CutReport | None]:
    """One intersection's traffic for `seconds` with no staged ego, cut as an import would cut
    it; the map and the clips are written under `root`. Returns the clip ids and the cut report."""
    from drivee2e_data.sources.synthetic.recording import generate_recording

    site, recording = generate_recording(seed, 0, seconds)
    pieces, report = split_recording(recording, site.intersection_map, clip_s, cut)
    store.write_map(root, site.intersection_map)
    for piece in pieces:
        store.write_scenario(root, piece)
    return [piece.scenario_id for piece in pieces], report


@dataclass(frozen=True)
class CurationRow:
    """One line of `drivee2e curate`."""

    scenario_id: str
    ego_id: str | None
    ego_source: str  # 'kept from the source', 'chosen', or 'none: ...'
    behavior: str
    tracks_dropped: int
    tracks_repaired: int


def curate(root: Path, on_scenario: Callable[[str], None] | None = None) -> list[CurationRow]:
    """Score and repair tracks, keep or choose each clip's ego, label its behaviour, and write
    the results into every bundle under `root`. Deterministic; safe to run again."""
    from drivee2e_data.curation import behavior, ego, quality, replay_flags

    counts: Counter[BehaviorCategory] = Counter()
    rows = []
    maps: dict[str, IntersectionMap] = {}
    for scenario_id in store.scenario_ids(root):
        scenario = store.read_scenario(root, scenario_id)
        if scenario.map_id not in maps:
            maps[scenario.map_id] = store.read_map(root, scenario.map_id)
        intersection_map = maps[scenario.map_id]
        kept, qualities = quality.assess_scenario(scenario, intersection_map)
        repaired = dataclasses.replace(scenario, tracks=tuple(kept), ego_id=None)
        kept_ids = {t.track_id for t in kept}
        ego_id, source, label = (
            None,
            "none: no vehicle valid in every frame on the map's lanes",
            None,
        )
        source_ego = scenario.ego_id in kept_ids and repaired.track(scenario.ego_id).valid.all()
        # a source ego that stands still shows no behaviour (a parked recording car): another
        # is chosen where one moves, unless the source labelled the clip itself
        still = (
            source_ego
            and (scenario.behavior is None or scenario.behavior.source == "labelled")
            and not ego.moves(repaired.track(scenario.ego_id))
        )
        choice = None
        if not source_ego or still:
            choice = ego.choose_ego(repaired, intersection_map, counts, behavior.label)
        if choice is not None:
            (ego_id, label) = choice
            source = "chosen (the source's ego stands still)" if still else "chosen"
        elif source_ego:
            ego_id, source = scenario.ego_id, "kept from the source"
            label = behavior.label(repaired, intersection_map, ego_id)
        metadata = dict(scenario.metadata)
        metadata.pop(replay_flags.METADATA_KEY, None)  # checked again for this curation
        if scenario.behavior is not None and scenario.behavior.source != "labelled":
            metadata[f"{scenario.behavior.source}_behavior"] = scenario.behavior.sub_scenario.value
        metadata["curation"] = {
            "ego": source,
            "actions": {q.track_id: q.actions for q in qualities if q.actions},
        }
        route = scenario.route
        if ego_id is not None and (route is None or ego_id != scenario.ego_id):
            route = ego.route_of(
                repaired.track(ego_id),
                behavior.lanes_driven(repaired.track(ego_id), intersection_map),
            )
        if label is not None:
            counts[label.category] += 1
        scores = [q.score for q in qualities]
        curated = dataclasses.replace(
            repaired,
            ego_id=ego_id,
            route=route if ego_id is not None else None,
            behavior=None if label is None else BehaviorLabel(label, "labelled"),
            quality={
                "mean_track_score": float(np.mean(scores)) if scores else 0.0,
                "min_track_score": float(np.min(scores)) if scores else 0.0,
                "tracks_dropped": float(sum(q.dropped for q in qualities)),
                "tracks_repaired": float(sum(bool(q.actions) and not q.dropped for q in qualities)),
            },
            metadata=metadata,
        )
        store.write_scenario(root, curated)
        rows.append(
            CurationRow(
                scenario_id,
                ego_id,
                source,
                "-" if label is None else label.value,
                sum(q.dropped for q in qualities),
                sum(bool(q.actions) and not q.dropped for q in qualities),
            )
        )
        if on_scenario is not None:
            on_scenario(scenario_id)
    return rows


def check_experts(
    root: Path,
    workers: int = 1,
    on_clip: Callable[[str, tuple[Flag, ...]], None] | None = None,
) -> dict[str, tuple[Flag, ...]]:
    """The expert-replay check (`agents/expert_check.py`) of every curated clip under `root`
    that this version has not checked yet, its flags written into the bundle's metadata as
    each clip is done (a rerun resumes); `on_clip(id, flags)` as each finishes. Returns the
    flags of every clip with an ego, checked now or before."""
    from drivee2e_data.curation.replay_flags import recorded_flags

    flags: dict[str, tuple[Flag, ...]] = {}
    todo = []
    for scenario_id in store.scenario_ids(root):
        meta = store.read_meta(root, scenario_id)
        if meta.get("ego_id") is None:
            continue
        done = recorded_flags(meta.get("metadata") or {})
        if done is None:
            todo.append(scenario_id)
        else:
            flags[scenario_id] = done
    jobs = [(Path(root), scenario_id) for scenario_id in todo]
    if workers <= 1 or len(jobs) <= 1:
        outcomes: Iterable[tuple[str, tuple[Flag, ...]]] = (_check_expert(*job) for job in jobs)
        for scenario_id, found in outcomes:
            flags[scenario_id] = found
            if on_clip is not None:
                on_clip(scenario_id, found)
    else:
        with ProcessPoolExecutor(max_workers=min(workers, len(jobs))) as pool:
            futures = [pool.submit(_check_expert, *job) for job in jobs]
            for future in as_completed(futures):
                scenario_id, found = future.result()
                flags[scenario_id] = found
                if on_clip is not None:
                    on_clip(scenario_id, found)
    return dict(sorted(flags.items()))


_maps: dict[tuple[str, str], IntersectionMap] = {}  # this process's maps, by (root, map id)


def _check_expert(root: Path, scenario_id: str) -> tuple[str, tuple[Flag, ...]]:
    """One clip's expert-replay check, written into its bundle."""
    from drivee2e_data.agents.expert_check import check_clip
    from drivee2e_data.curation.replay_flags import METADATA_KEY, record

    scenario = store.read_scenario(root, scenario_id)
    key = (str(root), scenario.map_id)
    if key not in _maps:
        _maps[key] = store.read_map(root, scenario.map_id)
    found = check_clip(scenario, _maps[key])
    store.write_metadata_entry(root, scenario_id, METADATA_KEY, record(found))
    return scenario_id, found


STATISTIC_PANELS = ("behaviour", "agent class", "weather", "time of day")


NO_MOTOR_VEHICLE = "no motor vehicle in the clip (nothing an ego could be)"
NOT_CHOSEN = "none chosen (not curated yet, or no vehicle seen throughout on the map's lanes)"


def clips_without_ego(summaries: list[ScenarioSummary]) -> Counter[str]:
    """How many clips have no ego, by why: no motor vehicle at all, or none chosen."""
    return Counter(
        NO_MOTOR_VEHICLE
        if not any(c.is_motor_vehicle and n for c, n in s.agents.items())
        else NOT_CHOSEN
        for s in summaries
        if s.ego_id is None
    )


def statistics(summaries: list[ScenarioSummary]) -> dict[str, Counter[str]]:
    """Distributions over a dataset: clips per behaviour category, weather and time of day;
    tracks per agent class. Every known value is listed, zeros included, in a fixed order."""
    from drivee2e_data.scenario import BehaviorCategory, TimeOfDay, Weather

    behaviour = Counter({c.value: 0 for c in BehaviorCategory})
    behaviour.update(s.behavior.split("-")[0] for s in summaries if s.behavior != "-")
    classes = Counter({c.value: 0 for c in AgentClass})
    for s in summaries:
        classes.update({c.value: n for c, n in s.agents.items()})
    weather = Counter({w.value: 0 for w in Weather})
    weather.update(s.weather for s in summaries)
    time_of_day = Counter({t.value: 0 for t in TimeOfDay})
    time_of_day.update(s.time_of_day for s in summaries)
    return dict(zip(STATISTIC_PANELS, (behaviour, classes, weather, time_of_day), strict=True))


def write_view(
    root: Path,
    scenario_id: str,
    frame: int,
    out: Path,
    renderer: str = "auto",
    weather: str | None = None,
    time_of_day: str | None = None,
) -> None:
    """Render the contact sheet of one frame of a stored scenario to a PNG, optionally under
    another weather or time of day (the sun is placed for that local solar hour)."""
    import dataclasses

    import cv2

    from drivee2e_data.scenario import TimeOfDay, Weather
    from drivee2e_data.sensors.contact_sheet import contact_sheet
    from drivee2e_data.sim.world import World
    from drivee2e_data.sun import start_time_for

    scenario = store.read_scenario(root, scenario_id)
    intersection_map = store.read_map(root, scenario.map_id)
    conditions = scenario.conditions
    if weather is not None:
        conditions = dataclasses.replace(conditions, weather=Weather(weather))
    if time_of_day is not None:
        start = start_time_for(
            TimeOfDay(time_of_day), conditions.start_time_utc.date(), intersection_map.origin
        )
        conditions = dataclasses.replace(
            conditions, time_of_day=TimeOfDay(time_of_day), start_time_utc=start
        )
    scenario = dataclasses.replace(scenario, conditions=conditions)
    if not 0 <= frame < scenario.num_frames:
        raise DriveE2EError(f"{scenario_id}: frame {frame} is outside 0..{scenario.num_frames - 1}")
    if scenario.ego is None:
        raise DriveE2EError(f"{scenario_id}: no ego to view from; run `drivee2e curate` first")
    with World(intersection_map, scenario, renderer) as world:
        sheet = contact_sheet(world, frame)
    ok, encoded = cv2.imencode(".png", sheet[:, :, ::-1])
    if not ok:
        raise DriveE2EError(f"{out}: PNG encoding failed")
    store.write_bytes_atomic(Path(out), encoded.tobytes())
