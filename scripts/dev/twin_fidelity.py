"""Twin fidelity, measured as the paper does, on synthetic and real maps:

    python scripts/dev/twin_fidelity.py DATA [--resolution 0.05] [--size 2000]

For every scenario of DATA (one per map): per map element (lanes, crosswalks, stop lines, road
marks) the IoU between the orthographic top-down segmentation render of the twin and the map's
polygons, over a square around the junction; the share of signal states replayed exactly (lamp
colour seen by a camera in front of each head, every 10th frame); and the agent size error between
the source box and the blueprint box (largest of length, width, height), median and worst per
class. Signal states are checked in the rendered image of each signal's head.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

import numpy as np

from drivee2e_data import store
from drivee2e_data.scenario import SignalState
from drivee2e_data.sim.fidelity import ELEMENTS, Grid, element_iou
from drivee2e_data.sim.world import World


def lamp_colour(world: World, head) -> SignalState:
    """The colour a camera 3 m in front of a signal head sees lit (OFF when none is)."""
    facing = np.array([np.cos(head.facing_yaw_rad), np.sin(head.facing_yaw_rad), 0.0])
    target = head.position_m + np.array([0.0, 0.0, 0.5])
    rgb = world.render(target + 3.0 * facing, target, 48, 48, 16.0).rgb.astype(int)
    red = ((rgb[:, :, 0] > 180) & (rgb[:, :, 1] < 80)).sum()
    yellow = ((rgb[:, :, 0] > 180) & (rgb[:, :, 1] > 150) & (rgb[:, :, 2] < 80)).sum()
    green = ((rgb[:, :, 1] > 180) & (rgb[:, :, 0] < 80)).sum()
    counts = {SignalState.RED: red, SignalState.YELLOW: yellow, SignalState.GREEN: green}
    best = max(counts, key=counts.get)
    return best if counts[best] >= 5 else SignalState.OFF


def signal_replay(world: World, intersection_map, every: int) -> tuple[int, int]:
    """(signal frames whose head shows the logged colour in the rendered image, checked), every
    `every`-th frame, one head per signal."""
    heads = {}
    for head in intersection_map.signal_heads:
        heads.setdefault(head.signal_id, head)
    exact = total = 0
    world.draw_radius_m = -1.0  # no agent between a camera and its head
    for frame in range(0, world.scenario.num_frames, every):
        world.set_time(frame)
        for signal in world.scenario.signals:
            if signal.signal_id not in heads:
                continue
            state = SignalState(int(signal.states[frame]))
            expected = (
                state
                if state in (SignalState.RED, SignalState.YELLOW, SignalState.GREEN)
                else SignalState.OFF
            )
            exact += lamp_colour(world, heads[signal.signal_id]) == expected
            total += 1
    return exact, total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--resolution", type=float, default=0.02, help="metres per pixel")
    parser.add_argument("--size", type=int, default=3000, help="pixels per side")
    parser.add_argument("--renderer", default="auto")
    parser.add_argument("--every", type=int, default=10, help="check signals every N frames")
    parser.add_argument(
        "--fine-resolution", type=float, default=0.004, help="metres per pixel for thin elements"
    )
    args = parser.parse_args()
    seen_maps: set[str] = set()
    size_errors: dict[str, list[float]] = defaultdict(list)
    print("| map | " + " | ".join(ELEMENTS) + " | signals exact |")
    print("|---" * (len(ELEMENTS) + 2) + "|")
    for scenario_id in store.scenario_ids(args.data):
        scenario = store.read_scenario(args.data, scenario_id)
        if scenario.map_id in seen_maps:
            continue
        seen_maps.add(scenario.map_id)
        intersection_map = store.read_map(args.data, scenario.map_id)
        with World(intersection_map, scenario, args.renderer) as world:
            stops = [s.line_m[:, :2] for s in intersection_map.stop_lines]
            centre = (
                np.concatenate(stops).mean(axis=0)
                if stops
                else scenario.tracks[0].xy_m[scenario.tracks[0].valid][0]
            )
            iou = element_iou(
                world,
                intersection_map,
                Grid(centre, args.size, args.resolution),
                args.fine_resolution,
            )
            exact, total = signal_replay(world, intersection_map, args.every)
            for track in scenario.tracks:
                blueprint = np.array(world.blueprints[track.track_id].size_m)
                logged = np.array(
                    [
                        np.median(getattr(track, n)[track.valid])
                        for n in ("length_m", "width_m", "height_m")
                    ]
                )
                size_errors[track.agent_class.value].append(float(np.abs(blueprint - logged).max()))
        cells = [("-" if np.isnan(iou[e]) else f"{100 * iou[e]:.1f}%") for e in ELEMENTS]
        signals = f"{exact}/{total}" if total else "no signals"
        print(f"| {scenario.map_id} | " + " | ".join(cells) + f" | {signals} |")
    print("\n| class | agents | size error median (m) | worst (m) |\n|---|---|---|---|")
    for name, errors in sorted(size_errors.items()):
        print(f"| {name} | {len(errors)} | {np.median(errors):.2f} | {max(errors):.2f} |")


if __name__ == "__main__":
    main()
