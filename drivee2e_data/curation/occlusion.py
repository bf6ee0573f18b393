"""The paper's occlusion ablation: vehicle-view variants of a clip that drop the agents the
ego's cameras never saw during expert collection, either only vehicles (`occ-vehicle`) or every
class (`occ-all`). The closed-loop harness replays a variant without those agents.

Seen means annotated with a nonzero visibility in some collected frame. An agent never present
in the collected frames (a log cut short with `--max-frames`) is kept: nothing says it was
unseen.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable

import numpy as np

from drivee2e_data.scenario import Scenario


class Variant(enum.Enum):
    COMPLETE = "complete"
    OCC_VEHICLE = "occ-vehicle"
    OCC_ALL = "occ-all"


def unseen_agents(
    scenario: Scenario, seen_track_ids: Iterable[str], collected_frames: range, variant: Variant
) -> list[str]:
    """Track ids the variant removes, sorted: present in a collected frame, never seen, and a
    motor vehicle (car, van, truck, bus) for `occ-vehicle`; none for `complete`."""
    if variant is Variant.COMPLETE:
        return []
    seen = set(seen_track_ids)
    frames = np.arange(collected_frames.start, min(collected_frames.stop, scenario.num_frames))
    removed = []
    for track in scenario.tracks:
        if track.track_id == scenario.ego_id or track.track_id in seen:
            continue
        if not track.valid[frames].any():
            continue
        if variant is Variant.OCC_VEHICLE and not track.agent_class.is_motor_vehicle:
            continue
        removed.append(track.track_id)
    return sorted(removed)
