"""Draw a top view of one scenario over its map: lanes, crosswalks, stop lines, kerbside,
buildings, signals, every track's path, and the ego's route.

    python scripts/plot_scenario.py DATA SCENARIO_ID --out top.png [--frame K] [--radius 70]

Needs the `viz` extra (matplotlib).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Polygon as PolygonPatch

from drivee2e_data import store
from drivee2e_data.geometry import box_corners_2d
from drivee2e_data.hdmap import IntersectionMap, MarkColour, MarkPattern
from drivee2e_data.scenario import AgentClass, Scenario, SignalState

CLASS_COLOUR = {
    AgentClass.CAR: "#1f77b4",
    AgentClass.VAN: "#17becf",
    AgentClass.TRUCK: "#8c564b",
    AgentClass.BUS: "#9467bd",
    AgentClass.PEDESTRIAN: "#2ca02c",
    AgentClass.CYCLIST: "#bcbd22",
    AgentClass.TRICYCLIST: "#e377c2",
    AgentClass.MOTORCYCLIST: "#ff7f0e",
}
SIGNAL_COLOUR = {
    SignalState.RED: "red",
    SignalState.YELLOW: "gold",
    SignalState.GREEN: "limegreen",
}


def draw_map(axes: plt.Axes, intersection_map: IntersectionMap) -> None:
    for area in intersection_map.drivable_areas:
        axes.add_patch(
            PolygonPatch(area.polygon_m, facecolor="#d9d9d9", edgecolor="none", zorder=0)
        )
    for area in intersection_map.sidewalks:
        axes.add_patch(
            PolygonPatch(area.polygon_m, facecolor="#f2e6d0", edgecolor="#b0a080", lw=0.5, zorder=1)
        )
    for building in intersection_map.buildings:
        axes.add_patch(
            PolygonPatch(
                building.footprint_m, facecolor="#a0a0b0", edgecolor="#505060", lw=0.5, zorder=1
            )
        )
    for tree in intersection_map.trees:
        axes.add_patch(
            plt.Circle(
                tuple(tree.position_m), tree.crown_radius_m, color="#7fbf7f", alpha=0.6, zorder=1
            )
        )
    for crosswalk in intersection_map.crosswalks:
        axes.add_patch(
            PolygonPatch(
                crosswalk.polygon_m,
                facecolor="white",
                edgecolor="#606060",
                hatch="///",
                lw=0.5,
                zorder=2,
            )
        )
    for lane in intersection_map.lanes:
        if lane.is_intersection:
            axes.plot(*lane.centerline_m[:, :2].T, color="#909090", lw=0.4, ls=":", zorder=2)
            continue
        for boundary, mark in (
            (lane.left_boundary_m, lane.left_mark),
            (lane.right_boundary_m, lane.right_mark),
        ):
            if mark.pattern == MarkPattern.NONE:
                continue
            colour = "#d4a800" if mark.colour == MarkColour.YELLOW else "white"
            style = "--" if mark.pattern == MarkPattern.DASHED else "-"
            width = 1.6 if mark.pattern == MarkPattern.DOUBLE_SOLID else 0.8
            axes.plot(*boundary[:, :2].T, color=colour, lw=width, ls=style, zorder=3)
    for stop_line in intersection_map.stop_lines:
        axes.plot(*stop_line.line_m[:, :2].T, color="black", lw=2.0, zorder=3)


def draw_scenario(axes: plt.Axes, scenario: Scenario, frame: int) -> None:
    for track in scenario.tracks:
        colour = "red" if track.track_id == scenario.ego_id else CLASS_COLOUR[track.agent_class]
        valid = track.valid
        axes.plot(
            track.x_m[valid],
            track.y_m[valid],
            color=colour,
            lw=1.6 if colour == "red" else 0.7,
            alpha=0.8,
            zorder=4,
        )
        if valid[frame]:
            corners = box_corners_2d(
                track.xy_m[frame], track.yaw_rad[frame], track.length_m[frame], track.width_m[frame]
            )
            axes.add_patch(
                PolygonPatch(corners, facecolor=colour, edgecolor="black", lw=0.5, zorder=5)
            )
    if scenario.route is not None:
        axes.plot(*scenario.route.waypoints_xy_m.T, color="red", lw=3, alpha=0.25, zorder=4)


def draw_signals(
    axes: plt.Axes, intersection_map: IntersectionMap, scenario: Scenario, frame: int
) -> None:
    states = {s.signal_id: s.state_at(frame) for s in scenario.signals}
    for head in intersection_map.signal_heads:
        colour = SIGNAL_COLOUR.get(states.get(head.signal_id, SignalState.UNKNOWN), "grey")
        marker = "o" if head.kind.value == "vehicle" else "s"
        axes.plot(
            *head.position_m[:2],
            marker=marker,
            color=colour,
            markeredgecolor="black",
            ms=6,
            zorder=6,
        )


def _view_centre(intersection_map: IntersectionMap, scenario: Scenario) -> np.ndarray:
    """The junction (mean of the stop lines), else the middle of the ego's drive."""
    if intersection_map.stop_lines:
        return np.concatenate([s.line_m[:, :2] for s in intersection_map.stop_lines]).mean(axis=0)
    if scenario.ego is not None:
        return scenario.ego.xy_m[scenario.ego.valid].mean(axis=0)
    return np.zeros(2)


def plot(root: Path, scenario_id: str, out: Path, frame: int | None, radius_m: float) -> None:
    scenario = store.read_scenario(root, scenario_id)
    intersection_map = store.read_map(root, scenario.map_id)
    frame = scenario.num_frames // 2 if frame is None else frame
    figure, axes = plt.subplots(figsize=(8, 8), dpi=110)
    axes.set_facecolor("#e8f0e0")
    draw_map(axes, intersection_map)
    draw_scenario(axes, scenario, frame)
    draw_signals(axes, intersection_map, scenario, frame)
    centre = _view_centre(intersection_map, scenario)
    axes.set_xlim(centre[0] - radius_m, centre[0] + radius_m)
    axes.set_ylim(centre[1] - radius_m, centre[1] + radius_m)
    axes.set_aspect("equal")
    label = scenario.behavior.sub_scenario.value if scenario.behavior else "-"
    axes.set_title(
        f"{scenario_id}: {label}, {scenario.conditions.weather.value}, "
        f"{scenario.conditions.time_of_day.value}, frame {frame}/{scenario.num_frames - 1}",
        fontsize=9,
    )
    handles = [plt.Line2D([], [], color=c, lw=2, label=k.value) for k, c in CLASS_COLOUR.items()]
    handles.append(plt.Line2D([], [], color="red", lw=2, label="ego"))
    axes.legend(handles=handles, loc="lower left", fontsize=7, ncol=3)
    figure.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out)
    plt.close(figure)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("scenario_id")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument(
        "--frame", type=int, default=None, help="frame whose boxes and signals are drawn"
    )
    parser.add_argument(
        "--radius", type=float, default=70.0, help="half-width of the view in metres"
    )
    args = parser.parse_args()
    plot(args.data, args.scenario_id, args.out, args.frame, args.radius)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
