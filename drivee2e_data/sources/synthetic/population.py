"""Who is on the road: background vehicles per lane, pedestrians per crosswalk, jaywalkers."""

from __future__ import annotations

import numpy as np
import shapely

from drivee2e_data.hdmap import TurnDirection
from drivee2e_data.scenario import AgentClass
from drivee2e_data.sources.common import TYPICAL_SIZE_M
from drivee2e_data.sources.synthetic.layout import (
    CROSSWALK_WIDTH_M,
    LANE_WIDTH_M,
    MAX_SIZE_SCALE,
    Arm,
    Layout,
    Movement,
    incoming_lane_id,
    pedestrian_signal_id,
)
from drivee2e_data.sources.synthetic.traffic import Crossing, PedestrianSpec, VehicleSpec

# desired speed range (m/s) per class
CLASS_SPEED_MPS = {
    AgentClass.CAR: (11.0, 15.0),
    AgentClass.VAN: (10.0, 14.0),
    AgentClass.TRUCK: (8.5, 12.0),
    AgentClass.BUS: (8.5, 11.5),
    AgentClass.CYCLIST: (4.0, 6.0),
    AgentClass.TRICYCLIST: (3.5, 5.5),
    AgentClass.MOTORCYCLIST: (8.0, 12.0),
}
VEHICLE_MIX = {
    AgentClass.CAR: 0.58,
    AgentClass.VAN: 0.1,
    AgentClass.TRUCK: 0.05,
    AgentClass.BUS: 0.05,
    AgentClass.CYCLIST: 0.08,
    AgentClass.MOTORCYCLIST: 0.08,
    AgentClass.TRICYCLIST: 0.06,
}
TURN_WEIGHT = {
    TurnDirection.STRAIGHT: 0.6,
    TurnDirection.LEFT: 0.2,
    TurnDirection.RIGHT: 0.2,
    TurnDirection.U_TURN: 0.03,
}
YELLOW_RUNNER_SHARE = 0.08
# a pedestrian at a kerb stands this far behind its line (centre; 0.4 m clear for a 0.6 m box):
# a turning car's corner passes close to the kerb, and people wait a step back from it
KERB_WAIT_M = 0.7
RIDERS = (AgentClass.CYCLIST, AgentClass.MOTORCYCLIST, AgentClass.TRICYCLIST)
LARGE = (AgentClass.TRUCK, AgentClass.BUS)


def sized(agent_class: AgentClass, rng: np.random.Generator) -> tuple[float, float, float]:
    base = TYPICAL_SIZE_M[agent_class]
    scale = rng.uniform(2.0 - MAX_SIZE_SCALE, MAX_SIZE_SCALE, size=3)
    return (float(base[0] * scale[0]), float(base[1] * scale[1]), float(base[2] * scale[2]))


def make_vehicle(
    agent_id: str,
    agent_class: AgentClass,
    movement: Movement,
    spawn_time_s: float,
    rng: np.random.Generator,
    runs_yellow: bool = False,
) -> VehicleSpec:
    length, width, height = sized(agent_class, rng)
    low, high = CLASS_SPEED_MPS[agent_class]
    return VehicleSpec(
        agent_id,
        agent_class,
        movement.movement_id,
        float(spawn_time_s),
        length,
        width,
        height,
        float(rng.uniform(low, high)),
        runs_yellow,
    )


def background_vehicles(
    layout: Layout, duration_s: float, rng: np.random.Generator, first_index: int = 0
) -> list[VehicleSpec]:
    """Poisson arrivals on every incoming lane, each choosing one of its lane's movements."""
    classes = list(VEHICLE_MIX)
    weights = np.array(list(VEHICLE_MIX.values()))
    vehicles: list[VehicleSpec] = []
    for arm in layout.arms:
        for lane in range(arm.lanes_in):
            lane_id = incoming_lane_id(arm.index, lane)
            options = [m for m in layout.movements if m.from_lane == lane_id and not m.abnormal]
            rate = rng.uniform(0.03, 0.09)  # vehicles per second on this lane
            time_s = rng.exponential(1.0 / rate)
            while time_s < duration_s:
                agent_class = classes[int(rng.choice(len(classes), p=weights / weights.sum()))]
                choices = [m for m in options if _allowed(agent_class, m, arm, lane)]
                if not choices:
                    agent_class, choices = AgentClass.CAR, options
                turn_weights = np.array([TURN_WEIGHT[m.turn] for m in choices])
                movement = choices[
                    int(rng.choice(len(choices), p=turn_weights / turn_weights.sum()))
                ]
                runs_yellow = agent_class.is_motor_vehicle and rng.random() < YELLOW_RUNNER_SHARE
                agent_id = f"v{first_index + len(vehicles):04d}"
                vehicles.append(
                    make_vehicle(agent_id, agent_class, movement, time_s, rng, runs_yellow)
                )
                time_s += rng.exponential(1.0 / rate)
    return sorted(vehicles, key=lambda v: (v.spawn_time_s, v.agent_id))


def _allowed(agent_class: AgentClass, movement: Movement, arm: Arm, lane: int) -> bool:
    if movement.turn == TurnDirection.U_TURN:
        return agent_class == AgentClass.CAR  # the loops are fitted to the largest car (layout)
    if agent_class in RIDERS:
        return lane == arm.lanes_in - 1 and movement.turn != TurnDirection.U_TURN
    if agent_class in LARGE:
        return movement.turn in (TurnDirection.STRAIGHT, TurnDirection.LEFT)
    return True


def crosswalk_crossing(arm: Arm) -> Crossing:
    near, far = arm.junction_edge_m, arm.junction_edge_m + CROSSWALK_WIDTH_M
    width_out, width_in = arm.lanes_out * LANE_WIDTH_M, arm.lanes_in * LANE_WIDTH_M
    polygon = shapely.Polygon(
        [
            arm.point(near, -width_out),
            arm.point(far, -width_out),
            arm.point(far, width_in),
            arm.point(near, width_in),
        ]
    )
    return Crossing(f"cw_a{arm.index}", polygon, pedestrian_signal_id(arm.index))


def crossing_pedestrian(
    agent_id: str,
    arm: Arm,
    along_m: float,
    from_left: bool,
    kerb_time_s: float,
    rng: np.random.Generator,
    crossing: Crossing,
    jaywalks: bool = False,
) -> PedestrianSpec:
    """A pedestrian crossing `arm` at distance `along_m`, reaching the kerb at `kerb_time_s`."""
    width_out, width_in = arm.lanes_out * LANE_WIDTH_M, arm.lanes_in * LANE_WIDTH_M
    start_side, end_side = (width_in, -width_out) if from_left else (-width_out, width_in)
    sign = np.sign(end_side)
    lateral_start = start_side + KERB_WAIT_M * np.sign(start_side)
    lateral_end = end_side + KERB_WAIT_M * sign
    back, onward = rng.uniform(2.0, 8.0), rng.uniform(6.0, 15.0)
    points = np.stack(
        [
            arm.point(along_m + back, lateral_start + 1.5 * np.sign(start_side)),
            arm.point(along_m, lateral_start),
            arm.point(along_m, lateral_end),
            arm.point(along_m + onward, lateral_end + 1.5 * sign),
        ]
    )
    segment = np.linalg.norm(np.diff(points, axis=0), axis=1)
    speed = float(rng.uniform(1.1, 1.6))
    height = float(rng.uniform(1.55, 1.9))
    return PedestrianSpec(
        agent_id=agent_id,
        spawn_time_s=float(kerb_time_s - segment[0] / speed),
        path_m=points,
        enter_s_m=float(segment[0]),
        leave_s_m=float(segment[0] + segment[1]),
        speed_mps=speed,
        crossing=crossing,
        size_m=(0.6, 0.6, height),
        jaywalks=jaywalks,
    )


def background_pedestrians(
    layout: Layout, duration_s: float, rng: np.random.Generator, first_index: int = 0
) -> list[PedestrianSpec]:
    """Pedestrians arriving at both ends of every crosswalk, walking on the signal."""
    pedestrians: list[PedestrianSpec] = []
    for arm in layout.arms:
        crossing = crosswalk_crossing(arm)
        rate = rng.uniform(0.02, 0.06)
        time_s = rng.exponential(1.0 / rate)
        while time_s < duration_s:
            from_left = bool(rng.random() < 0.5)
            # walkers keep to their right, so the two directions pass side by side
            lane_offset = (0.9 if from_left else -0.9) + rng.uniform(-0.3, 0.3)
            along = arm.junction_edge_m + 0.5 * CROSSWALK_WIDTH_M + lane_offset
            agent_id = f"p{first_index + len(pedestrians):04d}"
            pedestrians.append(
                crossing_pedestrian(agent_id, arm, along, from_left, time_s, rng, crossing)
            )
            time_s += rng.exponential(1.0 / rate)
    return sorted(pedestrians, key=lambda p: (p.spawn_time_s, p.agent_id))


def jaywalk_crossing(arm: Arm, along_m: float, crossing_id: str) -> Crossing:
    width_out, width_in = arm.lanes_out * LANE_WIDTH_M, arm.lanes_in * LANE_WIDTH_M
    line = shapely.LineString([arm.point(along_m, -width_out), arm.point(along_m, width_in)])
    return Crossing(crossing_id, line.buffer(1.0), None)
