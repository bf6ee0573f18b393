"""CommonRoad XML scenarios (formats 2018b and 2020a), read with the `commonroad-io` package.

Only its XML reader is used, which needs no protobuf: commonroad-io pins protobuf 3.20, which
the MCAP stack cannot use, so `scripts/install.sh` installs it without that pin. Obstacles
become tracks, lanelets lanes (with line markings and stop lines), traffic lights signal heads,
and their cycles signal timelines flagged `cycle_derived` (a plan, not measured states).
CommonRoad frames are local and metric already; the WGS84 origin is not in these files.
"""

from __future__ import annotations

import contextlib
import io
import logging
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import shapely

from drivee2e_data.errors import DriveE2EError, ScenarioFormatError
from drivee2e_data.hdmap import (
    Area,
    GeoOrigin,
    IntersectionMap,
    Lane,
    LaneMark,
    MarkColour,
    MarkPattern,
    SignalHead,
    StopLine,
    TurnDirection,
)
from drivee2e_data.scenario import (
    FRAME_PERIOD_NS,
    AgentClass,
    Conditions,
    Scenario,
    SignalState,
    SignalTimeline,
    TimeOfDay,
    Weather,
)
from drivee2e_data.sources.argoverse2 import Imported
from drivee2e_data.sources.common import TYPICAL_SIZE_M, ImportReport, resample_track
from drivee2e_data.sun import start_time_for

SOURCE = "commonroad"
NOMINAL_START = datetime(2020, 1, 1, 12, 0, tzinfo=timezone.utc)  # the files carry no time of day
CLASSES = {
    "CAR": AgentClass.CAR,
    "TAXI": AgentClass.CAR,
    "PRIORITY_VEHICLE": AgentClass.CAR,
    "TRUCK": AgentClass.TRUCK,
    "BUS": AgentClass.BUS,
    "BICYCLE": AgentClass.CYCLIST,
    "MOTORCYCLE": AgentClass.MOTORCYCLIST,
    "PEDESTRIAN": AgentClass.PEDESTRIAN,
}
MARKS = {
    "SOLID": LaneMark(MarkPattern.SOLID, MarkColour.WHITE),
    "BROAD_SOLID": LaneMark(MarkPattern.SOLID, MarkColour.WHITE),
    "DASHED": LaneMark(MarkPattern.DASHED, MarkColour.WHITE),
    "BROAD_DASHED": LaneMark(MarkPattern.DASHED, MarkColour.WHITE),
}
LIGHT_STATES = {
    "RED": SignalState.RED,
    "RED_YELLOW": SignalState.RED,  # 'prepare to go': still no entry
    "YELLOW": SignalState.YELLOW,
    "GREEN": SignalState.GREEN,
    "INACTIVE": SignalState.OFF,
}


def _read(path: Path):
    try:
        from commonroad.common.reader.file_reader_xml import XMLFileReader
    except ImportError as error:
        raise DriveE2EError(
            "the CommonRoad importer needs commonroad-io: run scripts/install.sh, or "
            "`pip install --no-deps commonroad-io` plus its requirements other than protobuf"
        ) from error
    if not path.is_file():
        raise ScenarioFormatError(f"{path}: file is missing")
    quiet = io.StringIO()
    logging.disable(logging.WARNING)
    try:
        with contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet):
            return XMLFileReader(str(path)).open()[0]
    except Exception as error:  # the reader raises many kinds; name the file once
        raise ScenarioFormatError(f"{path}: not a readable CommonRoad XML file ({error})") from None
    finally:
        logging.disable(logging.NOTSET)


def _mark(marking) -> LaneMark:
    return MARKS.get(getattr(marking, "name", ""), LaneMark())


def _turns(network) -> dict[int, TurnDirection]:
    turns: dict[int, TurnDirection] = {}
    for intersection in network.intersections:
        for incoming in intersection.incomings:
            for attribute, turn in (
                ("outgoing_left", TurnDirection.LEFT),
                ("outgoing_right", TurnDirection.RIGHT),
                ("outgoing_straight", TurnDirection.STRAIGHT),
            ):
                for lanelet_id in getattr(incoming, attribute, None) or ():
                    turns[int(lanelet_id)] = turn
    return turns


def _map(cr_scenario, map_id: str, report: ImportReport) -> IntersectionMap:
    network = cr_scenario.lanelet_network
    turns = _turns(network)
    light_ids = {int(light.traffic_light_id) for light in network.traffic_lights}
    lanes, stop_lines = [], []
    for lanelet in network.lanelets:
        lane_id = str(lanelet.lanelet_id)
        lights = sorted(int(i) for i in lanelet.traffic_lights if int(i) in light_ids)
        left_neighbor = (
            lanelet.adj_left if lanelet.adj_left and lanelet.adj_left_same_direction else None
        )
        right_neighbor = (
            lanelet.adj_right if lanelet.adj_right and lanelet.adj_right_same_direction else None
        )
        lanes.append(
            Lane(
                lane_id=lane_id,
                centerline_m=lanelet.center_vertices,
                left_boundary_m=lanelet.left_vertices,
                right_boundary_m=lanelet.right_vertices,
                left_mark=_mark(lanelet.line_marking_left_vertices),
                right_mark=_mark(lanelet.line_marking_right_vertices),
                turn_direction=turns.get(int(lanelet.lanelet_id), TurnDirection.NONE),
                is_intersection=int(lanelet.lanelet_id) in turns,
                predecessors=tuple(str(i) for i in lanelet.predecessor),
                successors=tuple(str(i) for i in lanelet.successor),
                left_neighbor=None if left_neighbor is None else str(left_neighbor),
                right_neighbor=None if right_neighbor is None else str(right_neighbor),
                signal_id=f"light_{lights[0]}" if lights else None,
            )
        )
        if lanelet.stop_line is not None:
            stop_lines.append(
                StopLine(
                    f"stop_{lane_id}",
                    np.stack([lanelet.stop_line.start, lanelet.stop_line.end]),
                    (lane_id,),
                )
            )
    heads = []
    for light in network.traffic_lights:
        controlled = [lane for lane in lanes if lane.signal_id == f"light_{light.traffic_light_id}"]
        facing = 0.0
        if controlled:
            end = controlled[0].centerline_m
            facing = float(np.arctan2(*(end[-2, :2] - end[-1, :2])[::-1]))  # towards the traffic
        heads.append(
            SignalHead(
                f"head_{light.traffic_light_id}",
                f"light_{light.traffic_light_id}",
                np.append(np.asarray(light.position, dtype=float)[:2], 5.0),
                facing,
                controlled_lane_ids=tuple(lane.lane_id for lane in controlled),
            )
        )
    road = shapely.union_all([lane.polygon() for lane in lanes]).buffer(0.05).buffer(-0.05)
    parts = [
        p for p in getattr(road, "geoms", [road]) if isinstance(p, shapely.Polygon) and p.area > 1.0
    ]
    areas = tuple(
        Area(f"road_{k}", np.asarray(p.exterior.coords)[:-1, :2]) for k, p in enumerate(parts)
    )
    report.warn(
        "CommonRoad files carry no WGS84 origin, time of day or weather: origin (0, 0), noon, clear"
    )
    return IntersectionMap(
        map_id=map_id,
        origin=GeoOrigin(0.0, 0.0),
        lanes=tuple(lanes),
        stop_lines=tuple(stop_lines),
        drivable_areas=areas,
        signal_heads=tuple(heads),
        metadata={"source": SOURCE, "origin": "unknown (not in the file)"},
    )


def import_commonroad(path: Path) -> Imported:
    """One CommonRoad XML file as a map and a scenario over the obstacles' time steps."""
    path = Path(path)
    report = ImportReport()
    cr_scenario = _read(path)
    dt_ns = round(float(cr_scenario.dt) * 1e9)
    if dt_ns != FRAME_PERIOD_NS:
        raise ScenarioFormatError(f"{path}: time step {cr_scenario.dt} s, expected 0.1 s (10 Hz)")
    name = str(cr_scenario.scenario_id)
    intersection_map = _map(cr_scenario, f"cr_{name}", report)
    states_by_obstacle = {}
    for obstacle in cr_scenario.dynamic_obstacles:
        states = [obstacle.initial_state]
        prediction = getattr(obstacle, "prediction", None)
        if prediction is not None and hasattr(prediction, "trajectory"):
            states += list(prediction.trajectory.state_list)
        states_by_obstacle[obstacle] = states
    last_step = max(
        (s.time_step for states in states_by_obstacle.values() for s in states), default=1
    )
    t0_ns = int(NOMINAL_START.timestamp()) * 1_000_000_000
    grid = t0_ns + FRAME_PERIOD_NS * np.arange(last_step + 1, dtype=np.int64)
    tracks = []
    for obstacle, states in states_by_obstacle.items():
        kind = obstacle.obstacle_type.name
        agent_class = CLASSES.get(kind)
        if agent_class is None:
            report.drop(kind, "not one of the 8 classes")
            continue
        shape = obstacle.obstacle_shape
        length = float(getattr(shape, "length", TYPICAL_SIZE_M[agent_class][0]))
        width = float(getattr(shape, "width", TYPICAL_SIZE_M[agent_class][1]))
        height = TYPICAL_SIZE_M[agent_class][2]
        steps = np.array([s.time_step for s in states])
        xy = np.array([s.position for s in states], dtype=float)
        yaw = np.array([s.orientation for s in states], dtype=float)
        size = np.tile([length, width, height], (len(states), 1))
        track = resample_track(
            str(obstacle.obstacle_id),
            agent_class,
            grid[steps],
            xy,
            np.full(len(states), height / 2),
            yaw,
            size,
            grid,
            {"source_class": kind, "height_source": "class default"},
        )
        if track is not None:
            tracks.append(track)
            report.keep(kind, agent_class)
    signals = tuple(
        SignalTimeline(
            f"light_{light.traffic_light_id}",
            np.array(
                [
                    LIGHT_STATES.get(
                        light.get_state_at_time_step(k).name, SignalState.UNKNOWN
                    ).value
                    for k in range(len(grid))
                ],
                np.uint8,
            ),
            origin="cycle_derived",
        )
        for light in cr_scenario.lanelet_network.traffic_lights
    )
    scenario = Scenario(
        scenario_id=f"cr_{name}",
        map_id=intersection_map.map_id,
        source=SOURCE,
        t_ns=grid,
        tracks=tuple(tracks),
        signals=signals,
        conditions=Conditions(
            Weather.CLEAR,
            TimeOfDay.NOON,
            start_time_for(TimeOfDay.NOON, NOMINAL_START.date(), intersection_map.origin),
        ),
        metadata={
            "source_file": path.name,
            "time": "not recorded; nominal noon (the sun placed for noon at the map origin)",
            "signals": "derived from the traffic-light cycles in the file",
        },
    )
    return Imported(intersection_map, scenario, report)
