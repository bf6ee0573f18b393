"""Where each agent drove in closed loop, over the intersection's map: the logged path (the
route, dashed black) beside each agent's driven path, with a cross where an infraction happened
and a square where the episode ended. Needs the viz extra (matplotlib).

    python scripts/plot_closedloop.py DATA CLIP [CLIP ...] --out closedloop.png
        [--admlp CKPT] [--camera CKPT] [--reactive]

Each panel is one clip; the agents are the expert, constant velocity, and AD-MLP and the camera
policy when their checkpoints are given. The episodes are run here, in process, exactly as
`drivee2e evaluate` runs them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from drivee2e_data import store
from drivee2e_data.agents.registry import build
from drivee2e_data.evaluate.episode import Episode, EpisodeOptions

COLOURS = {
    "expert": "#2a9d8f",
    "constant-velocity": "#e9c46a",
    "admlp": "#e76f51",
    "camera": "#6a4c93",
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("clips", nargs="+")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--admlp", type=Path, default=None)
    parser.add_argument("--camera", type=Path, default=None)
    parser.add_argument("--reactive", action="store_true")
    args = parser.parse_args()
    agents = [("expert", None), ("constant-velocity", None)]
    agents += [("admlp", args.admlp)] if args.admlp else []
    agents += [("camera", args.camera)] if args.camera else []
    figure, axes = plt.subplots(len(args.clips), 1, figsize=(11, 3.4 * len(args.clips)))
    axes = np.atleast_1d(axes)
    world = None
    for axis, clip in zip(axes, args.clips, strict=True):
        scenario = store.read_scenario(args.data, clip)
        intersection_map = store.read_map(args.data, scenario.map_id)
        for lane in intersection_map.lanes:
            for boundary in (lane.left_boundary_m, lane.right_boundary_m):
                axis.plot(*boundary[:, :2].T, color="#c8c8c8", linewidth=0.6, zorder=1)
        for crosswalk in intersection_map.crosswalks:
            axis.fill(*crosswalk.polygon_m[:, :2].T, color="#9ecae1", alpha=0.5, zorder=1)
        for stop_line in intersection_map.stop_lines:
            axis.plot(*stop_line.line_m[:, :2].T, color="#d62828", linewidth=1.2, zorder=2)
        route = None
        for name, checkpoint in agents:
            agent = build(name, checkpoint)
            if agent.sensors:
                from drivee2e_data.sim.world import World

                if world is None or world.intersection_map.map_id != scenario.map_id:
                    if world is not None:
                        world.close()
                    world = World(intersection_map, scenario)
                else:
                    world.replay(scenario)
            episode = Episode(scenario, intersection_map, agent, EpisodeOptions(args.reactive),
                              world=world if agent.sensors else None, keep_trace=True)  # fmt: skip
            result = episode.run()
            route = episode.route_xy
            driven = np.array([r.state.xy_m for r in result.trace])
            score = result.score
            label = f"{name}: DS {score.driving_score:.0f}, {score.status.replace('_', ' ')}"
            axis.plot(*driven.T, color=COLOURS[name], linewidth=2.0, label=label, zorder=4)
            for event in score.events:
                if 0 < event.frame <= len(driven):
                    axis.plot(*driven[event.frame - 1], "x", color=COLOURS[name], markersize=9,
                              markeredgewidth=2.5, zorder=5)  # fmt: skip
            axis.plot(*driven[-1], "s", color=COLOURS[name], markersize=6, zorder=5)
        axis.plot(*route.T, "--", color="black", linewidth=1.2, label="logged path", zorder=3)
        axis.plot(*route[0], "o", color="black", markersize=6, zorder=5)
        margin = 12.0
        low, high = route.min(0) - margin, route.max(0) + margin
        axis.set_xlim(low[0], high[0])
        axis.set_ylim(low[1], high[1])
        axis.set_aspect("equal")
        behaviour = scenario.behavior.sub_scenario.value if scenario.behavior else "-"
        axis.set_title(f"{clip} ({behaviour})", fontsize=10)
        axis.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8, framealpha=0.9)
        axis.set_xticks([])
        axis.set_yticks([])
    if world is not None:
        world.close()
    figure.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
