"""A centre-line-only version of a stored clip's map, as V2X-Seq maps come (lane centre lines,
crosswalks and signals; no boundaries, paint, stop lines, drivable areas, sidewalks or
buildings), with its markings derived again (`sources/markings.py`):

    python scripts/dev/centerline_only.py DATA SCENARIO_ID --out DATA2

writes the map as `<map id>_centerline` and the clip pointing at it into DATA2, for
`drivee2e view` and `scripts/dev/twin_fidelity.py`; prints how many lane sides got the mark the
original map paints there.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from drivee2e_data import store
from drivee2e_data.geometry import offset_polyline
from drivee2e_data.hdmap import IntersectionMap, LaneMark
from drivee2e_data.sources.markings import derive_markings
from drivee2e_data.sources.v2x_seq import LANE_HALF_WIDTH_M


def centerline_only(intersection_map: IntersectionMap, derive: bool = True) -> IntersectionMap:
    """What a V2X-Seq map of the same site would hold, markings derived (unless not `derive`)."""
    lanes = []
    for lane in intersection_map.lanes:
        centre = lane.centerline_m
        left = np.column_stack([offset_polyline(centre, LANE_HALF_WIDTH_M), centre[:, 2]])
        right = np.column_stack([offset_polyline(centre, -LANE_HALF_WIDTH_M), centre[:, 2]])
        lanes.append(
            dataclasses.replace(
                lane,
                left_boundary_m=left,
                right_boundary_m=right,
                left_mark=LaneMark(),
                right_mark=LaneMark(),
            )
        )
    signalised = {lane.lane_id for lane in lanes if lane.signal_id}
    controlled = [
        lane.lane_id
        for lane in lanes
        if not lane.is_intersection and (lane.signal_id or signalised & set(lane.successors))
    ]
    bare = IntersectionMap(
        map_id=f"{intersection_map.map_id}_centerline",
        origin=intersection_map.origin,
        lanes=tuple(lanes),
        crosswalks=intersection_map.crosswalks,
        signal_heads=intersection_map.signal_heads,
        metadata={"source": "centre lines of " + intersection_map.map_id},
    )
    return derive_markings(bare, controlled) if derive else bare


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("scenario_id")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--bare", action="store_true", help="leave the markings out (as before)")
    args = parser.parse_args()
    scenario = store.read_scenario(args.data, args.scenario_id)
    original = store.read_map(args.data, scenario.map_id)
    derived = centerline_only(original, derive=not args.bare)
    same = total = 0
    for before, after in zip(original.lanes, derived.lanes, strict=True):
        if before.is_intersection:
            continue
        same += (before.left_mark == after.left_mark) + (before.right_mark == after.right_mark)
        total += 2
    store.write_map(args.out, derived)
    store.write_scenario(args.out, dataclasses.replace(scenario, map_id=derived.map_id))
    print(
        f"{derived.map_id}: {same}/{total} lane sides marked as the original paints them; "
        f"{derived.metadata.get('derived_stop_lines', 0)} stop lines derived "
        f"(the original has {len(original.stop_lines)})"
    )


if __name__ == "__main__":
    main()
