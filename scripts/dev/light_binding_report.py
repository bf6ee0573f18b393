"""How many frames' traffic-light label changes with the per-frame binding signal.

    python scripts/dev/light_binding_report.py DATA [DATA ...]

For every curated clip with an ego and a route under each data root: the ego's light at every
frame as the loaders gave it before 2026-11-24 (the state of the first signal along the route,
for the whole clip) and as they give it now (`binding.binding_signals`: the signal at the next
signal-controlled stop line ahead of the ego's front bumper, none once it has crossed the last),
and the frames where the two differ, by what they became.
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

import numpy as np

from drivee2e_data import store
from drivee2e_data.binding import binding_signals, front_bumper
from drivee2e_data.scenario import SignalState

SHOWN = ("RED", "YELLOW", "GREEN")


def _state(signals: dict, signal_id: str | None, frame: int) -> str:
    if signal_id is None or signal_id not in signals:
        return "NONE"
    name = SignalState(int(signals[signal_id].states[frame])).name
    return name if name in SHOWN else "NONE"


def clip_report(root: Path, scenario_id: str) -> tuple[int, Counter] | None:
    """(frames, Counter of (before, after) over the frames that changed), or None for a clip
    without an ego or a route."""
    scenario = store.read_scenario(root, scenario_id)
    if scenario.ego is None or scenario.route is None:
        return None
    intersection_map = store.read_map(root, scenario.map_id)
    ego = scenario.ego
    signals = {s.signal_id: s for s in scenario.signals}
    controlling = {lane.lane_id: lane.signal_id for lane in intersection_map.lanes}
    first = next(
        (controlling[k] for k in scenario.route.lane_ids if controlling.get(k) is not None), None
    )
    front = front_bumper(ego.xy_m, ego.yaw_rad, float(np.median(ego.length_m)))
    bound = binding_signals(intersection_map, scenario.route.lane_ids, front)
    changes: Counter = Counter()
    for frame in range(scenario.num_frames):
        before, after = _state(signals, first, frame), _state(signals, bound[frame], frame)
        if before != after:
            changes[(before, after)] += 1
    return scenario.num_frames, changes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("roots", type=Path, nargs="+")
    args = parser.parse_args()
    print("| clip | frames | frames changed | how (before -> after: frames) |")
    print("|---|---|---|---|")
    total_frames = total_changed = clips = 0
    for root in args.roots:
        for scenario_id in store.scenario_ids(root):
            report = clip_report(root, scenario_id)
            if report is None:
                continue
            frames, changes = report
            changed = sum(changes.values())
            how = ", ".join(f"{a} -> {b}: {n}" for (a, b), n in sorted(changes.items())) or "-"
            print(
                f"| {scenario_id} | {frames} | {changed} ({100 * changed / frames:.0f}%) | {how} |"
            )
            total_frames, total_changed, clips = (
                total_frames + frames,
                total_changed + changed,
                clips + 1,
            )
    if clips:
        print(f"\n{clips} clips, {total_frames} frames, {total_changed} changed "
              f"({100 * total_changed / max(total_frames, 1):.1f}%)")  # fmt: skip


if __name__ == "__main__":
    main()
