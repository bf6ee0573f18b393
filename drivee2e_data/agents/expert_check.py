"""The expert-replay check of curation: the log-replay expert drives each clip in closed loop,
with every other agent on its log and again reactive, under the benchmark's own rules; a clip
where it breaks one (a collision by the shared definition of `collision.py`, a red light,
driving off the road or outside the route's lanes, a route deviation, ...) is flagged with the
rule, the frame and the partner, and `drivee2e split` leaves it out of the manifests.

A recorded path that runs over a pedestrian is a wrong label for imitation learning, and a
benchmark whose reference fails a clip cannot tell a model's failure from the data's. Real
clips get the same check; what their box and map noise may cause is tolerated by the rules'
own margins (`metrics.closedloop.OFF_ROAD_TOLERANCE_M`), not by this check.
"""

from __future__ import annotations

from drivee2e_data.agents.expert import LogReplayExpert
from drivee2e_data.curation.replay_flags import Flag
from drivee2e_data.evaluate.episode import Episode, EpisodeOptions, EpisodeResult
from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.metrics.closedloop import ENDS_ROUTE, PENALTY, MapRules
from drivee2e_data.scenario import Scenario

MODES = (("log replay", False), ("reactive", True))


def check_clip(
    scenario: Scenario, intersection_map: IntersectionMap, map_rules: MapRules | None = None
) -> tuple[Flag, ...]:
    """The flags of the expert's drives of `scenario` (empty: clean). The scenario needs an
    ego; `map_rules` (built for its route) may be passed to save building them twice."""
    if scenario.ego is None:
        raise ValueError(f"{scenario.scenario_id}: no ego to check (curate it first)")
    if map_rules is None:
        route_lanes = scenario.route.lane_ids if scenario.route is not None else ()
        map_rules = MapRules(intersection_map, route_lanes)
    flags: list[Flag] = []
    for mode, reactive in MODES:
        episode = Episode(
            scenario,
            intersection_map,
            LogReplayExpert(),
            EpisodeOptions(reactive=reactive),
            map_rules=map_rules,
        )
        flags.extend(flags_of(episode.run(), mode))
    return tuple(flags)


def flags_of(result: EpisodeResult, mode: str) -> list[Flag]:
    """What keeps an episode from success, as flags."""
    flags = [
        Flag(mode, e.infraction.value, e.frame, e.partner_id or "", e.detail)
        for e in result.score.events
        if e.infraction in PENALTY or e.infraction in ENDS_ROUTE
    ]
    if result.off_road_first_step >= 0:
        share = f"{result.off_road_percent:.1f}% of the route"
        flags.append(Flag(mode, "off_road", result.off_road_first_step, "", share))
    elif result.score.outside_lanes_percent > 0.0:
        share = f"{result.score.outside_lanes_percent:.1f}% of the route"
        flags.append(Flag(mode, "outside_route_lanes", result.outside_first_step, "", share))
    if not flags and not result.score.success:
        completion = f"{result.score.route_completion:.1f}% of the route"
        flags.append(Flag(mode, "incomplete", result.steps, "", completion))
    return flags
