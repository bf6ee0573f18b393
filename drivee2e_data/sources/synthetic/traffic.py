"""Microscopic traffic on a layout: IDM car-following, signals, junction conflicts, pedestrians.

Vehicles drive their path's arclength with the Intelligent Driver Model; every obstacle (the
vehicle ahead, a red stop line, a conflict zone held by another vehicle, a pedestrian on a
crossing) is an IDM leader and the most restrictive one wins. At a conflict zone the vehicle that
is already committed to it (inside, or too close to stop) goes first; otherwise the higher-ranked
movement (straight > right > left > U-turn > abnormal) goes first and the other accepts a gap.
Pedestrians walk their crossing on the walk signal and wait at the kerb for moving vehicles.
"""

from __future__ import annotations

import bisect
import enum
import math
from dataclasses import dataclass, field

import numpy as np
import shapely
from numpy.typing import NDArray

from drivee2e_data.geometry import polyline_arclength
from drivee2e_data.hdmap import TurnDirection
from drivee2e_data.scenario import AgentClass, SignalState
from drivee2e_data.sources.synthetic.paths import Path, PathNetwork, Zone
from drivee2e_data.sources.synthetic.signals import SignalPlan

STEP_S = 0.1
IDM_HEADWAY_S = 1.4
IDM_MIN_GAP_M = 2.0
IDM_EXPONENT = 4
MAX_BRAKE_MPS2 = 8.0  # emergency braking; the physics test bounds deceleration by this
COMMIT_BRAKE_MPS2 = 6.0  # a vehicle that would need harder braking to stop is committed
YELLOW_STOP_BRAKE_MPS2 = 3.5  # drivers stop at yellow when this deceleration suffices
GAP_MARGIN_S = 1.5  # extra time a yielding vehicle keeps between itself and the other
SPAWN_CLEARANCE_M = 8.0
PEDESTRIAN_REACH_M = 2.5
# walkers keep their centres this far apart (two 0.6 m boxes at any angle stay clear): a later
# one queues behind an earlier one at a kerb, or keeps behind it on a crossing
WALKER_GAP_M = 0.9
HELD_MPS = 1.0  # a vehicle this slow and held by something ahead is not about to arrive
FAR_AWAY_S = 9.0  # a vehicle further than this from a conflict zone cannot contest it yet

# (max acceleration, comfortable deceleration) per class, m/s^2
DYNAMICS = {
    AgentClass.CAR: (1.8, 2.5),
    AgentClass.VAN: (1.5, 2.5),
    AgentClass.TRUCK: (1.0, 2.0),
    AgentClass.BUS: (1.0, 2.0),
    AgentClass.CYCLIST: (1.0, 2.0),
    AgentClass.TRICYCLIST: (0.8, 2.0),
    AgentClass.MOTORCYCLIST: (2.0, 3.0),
}
MOVEMENT_RANK = {
    TurnDirection.STRAIGHT: 3,
    TurnDirection.RIGHT: 2,
    TurnDirection.LEFT: 1,
    TurnDirection.U_TURN: 0,
}


class Constraint(enum.IntEnum):
    """What limited a vehicle's acceleration at a step (the binding IDM leader)."""

    FREE = 0
    LEADER = 1
    RED = 2
    YELLOW = 3
    VEHICLE = 4
    VRU = 5


@dataclass(frozen=True)
class VehicleSpec:
    agent_id: str
    agent_class: AgentClass
    movement_id: str
    spawn_time_s: float
    length_m: float
    width_m: float
    height_m: float
    desired_speed_mps: float
    runs_yellow: bool = False


@dataclass(frozen=True)
class Crossing:
    """Where pedestrians cross a road: a crosswalk, or a jaywalker's own line across it."""

    crossing_id: str
    polygon: shapely.Geometry
    signal_id: str | None


@dataclass(frozen=True)
class PedestrianSpec:
    agent_id: str
    spawn_time_s: float
    path_m: NDArray[np.float64]  # (N, 2): kerbside approach, the crossing, the walk away
    enter_s_m: float  # arclength where the road starts
    leave_s_m: float  # arclength where the road ends
    speed_mps: float
    crossing: Crossing
    size_m: tuple[float, float, float] = (0.6, 0.6, 1.75)
    jaywalks: bool = False  # crosses whatever the signal shows


@dataclass
class SimResult:
    """Per agent (rows: vehicles then pedestrians) and step: pose, speed, validity, constraints."""

    agent_ids: list[str]
    x_m: NDArray[np.float64]
    y_m: NDArray[np.float64]
    yaw_rad: NDArray[np.float64]
    speed_mps: NDArray[np.float64]
    accel_mps2: NDArray[np.float64]
    valid: NDArray[np.bool_]
    s_m: NDArray[np.float64]  # arclength on the agent's own path
    constraint: NDArray[np.int8]  # Constraint per step (vehicles)
    constraint_other: NDArray[np.int32]  # row of the agent behind a VEHICLE/VRU constraint, or -1
    signal_states: dict[str, NDArray[np.uint8]]
    times_s: NDArray[np.float64]
    stop_line_state: dict[str, tuple[int, SignalState]] = field(default_factory=dict)


def travel_time_s(distance_m: float, speed_mps: float, accel_mps2: float, top_mps: float) -> float:
    """Time to cover `distance_m` from `speed_mps`, accelerating at `accel_mps2` up to `top_mps`."""
    if distance_m <= 0:
        return 0.0
    top = max(top_mps, speed_mps, 0.5)
    ramp_time = (top - speed_mps) / accel_mps2
    ramp_distance = speed_mps * ramp_time + 0.5 * accel_mps2 * ramp_time**2
    if ramp_distance >= distance_m:
        return (-speed_mps + math.sqrt(speed_mps**2 + 2 * accel_mps2 * distance_m)) / accel_mps2
    return ramp_time + (distance_m - ramp_distance) / top


class TrafficSimulation:
    """Runs vehicles and pedestrians over `duration_s` at 10 Hz. Deterministic: no randomness."""

    def __init__(
        self,
        network: PathNetwork,
        plan: SignalPlan,
        vehicles: list[VehicleSpec],
        pedestrians: list[PedestrianSpec],
        duration_s: float,
    ) -> None:
        self.network, self.plan = network, plan
        self.vehicles, self.pedestrians = vehicles, pedestrians
        self.steps = round(duration_s / STEP_S) + 1
        self.paths: list[Path] = [network.paths[v.movement_id] for v in vehicles]
        # each walker's path (its arclength too) as plain floats: read a few hundred thousand
        # times a clip, by bisect and `_interp`
        self.ped_s = [polyline_arclength(p.path_m).tolist() for p in pedestrians]
        self.ped_x = [p.path_m[:, 0].tolist() for p in pedestrians]
        self.ped_y = [p.path_m[:, 1].tolist() for p in pedestrians]
        self.max_accel = [DYNAMICS[v.agent_class][0] for v in vehicles]
        self.comfort_brake = [DYNAMICS[v.agent_class][1] for v in vehicles]
        self.half_length = [0.5 * v.length_m for v in vehicles]
        self.rank = [
            -1 if path.movement.abnormal else MOVEMENT_RANK[path.movement.turn]
            for path in self.paths
        ]
        self.vehicle_xy = np.full((len(vehicles), 2), np.nan)
        self.vehicle_yaw = np.full(len(vehicles), np.nan)
        self.held = [False] * len(vehicles)  # whether an obstacle bound each vehicle last step
        self._ped_state = ["approach"] * len(pedestrians)

    # ------------------------------------------------------------------ main loop

    def run(self) -> SimResult:
        count = len(self.vehicles) + len(self.pedestrians)
        shape = (count, self.steps)
        result = SimResult(
            agent_ids=[v.agent_id for v in self.vehicles] + [p.agent_id for p in self.pedestrians],
            x_m=np.full(shape, np.nan),
            y_m=np.full(shape, np.nan),
            yaw_rad=np.full(shape, np.nan),
            speed_mps=np.full(shape, np.nan),
            accel_mps2=np.full(shape, np.nan),
            valid=np.zeros(shape, bool),
            s_m=np.full(shape, np.nan),
            constraint=np.zeros(shape, np.int8),
            constraint_other=np.full(shape, -1, np.int32),
            signal_states={},
            times_s=np.arange(self.steps) * STEP_S,
        )
        result.signal_states = self.plan.timeline(result.times_s)
        s = np.zeros(count)
        v = np.zeros(count)
        state = np.zeros(count, np.int8)  # 0 waiting to spawn, 1 alive, 2 gone
        yellow_go: dict[int, bool] = {}
        for step in range(self.steps):
            time_s = step * STEP_S
            states = {k: SignalState(int(t[step])) for k, t in result.signal_states.items()}
            self._spawn(time_s, s, v, state)
            accel = self._vehicle_accelerations(step, s, v, state, states, yellow_go, result)
            self._advance_vehicles(step, s, v, state, accel, result)
            self._advance_pedestrians(time_s, s, v, state, states)
            self._record(step, s, v, state, accel, result)
        return result

    def _spawn(self, time_s: float, s: NDArray, v: NDArray, state: NDArray) -> None:
        for i, spec in enumerate(self.vehicles):
            if state[i] != 0 or spec.spawn_time_s > time_s:
                continue
            first_lane = self.paths[i].lanes[0][0]
            gap = self._entry_gap(first_lane, s, state)
            if gap < spec.length_m + SPAWN_CLEARANCE_M:
                continue  # the lane's entry is occupied: spawn when it frees up
            s[i] = 0.5 * spec.length_m
            brake = self.comfort_brake[i]
            safe = math.sqrt(max(0.0, 2 * brake * (gap - spec.length_m - IDM_MIN_GAP_M)))
            v[i] = min(spec.desired_speed_mps, safe)
            state[i] = 1
        offset = len(self.vehicles)
        for k, spec in enumerate(self.pedestrians):
            if state[offset + k] == 0 and spec.spawn_time_s <= time_s:
                state[offset + k], s[offset + k], v[offset + k] = 1, 0.0, spec.speed_mps

    def _entry_gap(self, lane_id: str, s: NDArray, state: NDArray) -> float:
        gap = math.inf
        for j, path in enumerate(self.paths):
            if state[j] == 1 and path.lanes[0][0] == lane_id:
                gap = min(gap, s[j] - 0.5 * self.vehicles[j].length_m)
        return gap

    # ------------------------------------------------------------------ vehicles

    def _vehicle_accelerations(
        self,
        step: int,
        s: NDArray,
        v: NDArray,
        state: NDArray,
        states: dict[str, SignalState],
        yellow_go: dict[int, bool],
        result: SimResult,
    ) -> NDArray:
        alive = [i for i in range(len(self.vehicles)) if state[i] == 1]
        self._active_pedestrians = [
            k for k, phase in enumerate(self._ped_state) if phase == "crossing"
        ]
        self._ped_xy = {
            k: self._ped_position(k, s[len(self.vehicles) + k]) for k in self._active_pedestrians
        }
        occupancy = self._occupancy(alive, s)
        on_movement: dict[str, list[int]] = {}
        for i in alive:
            on_movement.setdefault(self.vehicles[i].movement_id, []).append(i)
        accel = np.zeros(len(s))
        s_list, v_list = s.tolist(), v.tolist()  # plain floats: much faster in these loops
        self._zone_cache: dict[tuple[str, float, float], list[tuple[int, bool, float]]] = {}
        for i in alive:
            obstacles = self._obstacles(
                i, s_list, v_list, states, yellow_go, occupancy, on_movement
            )
            free = self._idm_free(i, s_list, v_list)
            best, kind, other = free, Constraint.FREE, -1
            for gap, speed, obstacle_kind, obstacle_other in obstacles:
                candidate = self._idm(i, v_list, gap, speed, free)
                if candidate < best:
                    best, kind, other = candidate, obstacle_kind, obstacle_other
            accel[i] = best
            self.held[i] = kind != Constraint.FREE
            result.constraint[i, step] = kind
            result.constraint_other[i, step] = other
        return accel

    def _occupancy(self, alive: list[int], s: NDArray) -> dict[str, list[tuple[int, float, float]]]:
        """Per lane id: (vehicle, rear, front) in that lane's own arclength."""
        occupancy: dict[str, list[tuple[int, float, float]]] = {}
        for i in alive:
            half = 0.5 * self.vehicles[i].length_m
            rear, front = s[i] - half, s[i] + half
            for lane_id, start, end in self.paths[i].lanes:
                if front > start and rear < end:
                    occupancy.setdefault(lane_id, []).append((i, rear - start, front - start))
        return occupancy

    def _obstacles(
        self,
        i: int,
        s: NDArray,
        v: NDArray,
        states: dict[str, SignalState],
        yellow_go: dict[int, bool],
        occupancy: dict[str, list[tuple[int, float, float]]],
        on_movement: dict[str, list[int]],
    ) -> list[tuple[float, float, Constraint, int]]:
        """(gap to the obstacle, its speed, kind, agent row) for every obstacle ahead of i."""
        front = s[i] + 0.5 * self.vehicles[i].length_m
        obstacles = []
        leader = self._leader(i, s, v, occupancy)
        if leader is not None:
            obstacles.append((leader[0], leader[1], Constraint.LEADER, leader[2]))
        signal = self._signal_obstacle(i, front, v[i], states, yellow_go)
        if signal is not None:
            obstacles.append(signal)
        obstacles.extend(self._conflict_obstacles(i, s, v, states, yellow_go, on_movement))
        obstacles.extend(self._crossing_obstacles(i, s, v))
        return obstacles

    def _leader(
        self, i: int, s: NDArray, v: NDArray, occupancy: dict[str, list[tuple[int, float, float]]]
    ) -> tuple[float, float, int] | None:
        front = s[i] + 0.5 * self.vehicles[i].length_m
        best: tuple[float, float, int] | None = None
        for lane_id, start, end in self.paths[i].lanes:
            if end <= front - 20.0 or start > front + 80.0:
                continue
            for j, rear_j, front_j in occupancy.get(lane_id, ()):
                if j == i or start + front_j <= front:
                    continue
                gap = max(start + rear_j - front, 0.05)
                if best is None or gap < best[0]:
                    best = (gap, float(v[j]), j)
        return best

    def _will_stop_for_signal(
        self, i: int, front: float, states: dict[str, SignalState], yellow_go: dict[int, bool]
    ) -> bool:
        path = self.paths[i]
        if front >= path.stop_s_m:
            return False
        signal = states[path.movement.signal_id]
        if signal == SignalState.RED:
            return True
        return signal == SignalState.YELLOW and not yellow_go.get(i, True)

    def _signal_obstacle(
        self,
        i: int,
        front: float,
        speed: float,
        states: dict[str, SignalState],
        yellow_go: dict[int, bool],
    ) -> tuple[float, float, Constraint, int] | None:
        path, spec = self.paths[i], self.vehicles[i]
        signal = states[path.movement.signal_id]
        distance = path.stop_s_m - front
        if signal != SignalState.YELLOW:
            yellow_go.pop(i, None)
        if distance < 0:
            return None
        if signal == SignalState.YELLOW:
            if i not in yellow_go:
                if spec.runs_yellow:
                    yellow_go[i] = distance <= 2.5 * max(speed, 0.1)
                else:
                    yellow_go[i] = distance < speed**2 / (2 * YELLOW_STOP_BRAKE_MPS2) + 0.5
            if yellow_go[i]:
                return None
            return (distance + IDM_MIN_GAP_M - 0.5, 0.0, Constraint.YELLOW, -1)
        if signal == SignalState.RED:
            return (distance + IDM_MIN_GAP_M - 0.5, 0.0, Constraint.RED, -1)
        return None

    def _committed(self, j: int, front: float, speed: float, zone_start: float) -> bool:
        """Whether vehicle j holds a zone: inside it, or too close to stop before it."""
        return front >= zone_start - speed**2 / (2 * COMMIT_BRAKE_MPS2) - 0.5

    def _eta(self, j: int, front: float, speed: float, target: float) -> float:
        return travel_time_s(
            target - front, speed, self.max_accel[j], self.vehicles[j].desired_speed_mps
        )

    def _conflict_obstacles(
        self,
        i: int,
        s: NDArray,
        v: NDArray,
        states: dict[str, SignalState],
        yellow_go: dict[int, bool],
        on_movement: dict[str, list[int]],
    ) -> list[tuple[float, float, Constraint, int]]:
        spec = self.vehicles[i]
        front, rear = s[i] + self.half_length[i], s[i] - self.half_length[i]
        rank_i = self.rank[i]
        obstacles: list[tuple[float, float, Constraint, int]] = []
        if front < self.paths[i].stop_s_m - 60.0:
            return obstacles
        for zone in self.network.zones[spec.movement_id]:
            others = on_movement.get(zone.other)
            if not others or rear >= zone.end_m or zone.start_m - front > 60.0:
                continue
            if self._committed(i, front, v[i], zone.start_m):
                continue
            gap = zone.start_m - front + IDM_MIN_GAP_M - 1.0
            eta_i = clear_i = -1.0
            for j, committed_j, eta_j in self._contenders(zone, others, s, v, states, yellow_go):
                if committed_j:
                    obstacles.append((gap, 0.0, Constraint.VEHICLE, j))
                    continue
                if self.rank[j] < rank_i:
                    continue
                if eta_i < 0:
                    eta_i = self._eta(i, front, v[i], zone.start_m)
                    clear_i = self._eta(i, front, v[i], zone.end_m + spec.length_m)
                if (self.rank[j], -eta_j, -j) <= (rank_i, -eta_i, -i):
                    continue  # i goes first
                if eta_j < clear_i + GAP_MARGIN_S:
                    obstacles.append((gap, 0.0, Constraint.VEHICLE, j))
        return obstacles

    def _contenders(
        self,
        zone: Zone,
        others: list[int],
        s: list[float],
        v: list[float],
        states: dict[str, SignalState],
        yellow_go: dict[int, bool],
    ) -> list[tuple[int, bool, float]]:
        """(vehicle, holds the zone, time to reach it) for the other side of a zone; cached per step."""
        key = (zone.other, zone.other_start_m, zone.other_end_m)
        cached = self._zone_cache.get(key)
        if cached is not None:
            return cached
        contenders = []
        for j in others:
            front_j, rear_j = s[j] + self.half_length[j], s[j] - self.half_length[j]
            distance = zone.other_start_m - front_j
            if rear_j >= zone.other_end_m:
                continue
            if distance > FAR_AWAY_S * max(v[j], self.vehicles[j].desired_speed_mps):
                continue  # too far away to matter yet
            if self._will_stop_for_signal(j, front_j, states, yellow_go):
                continue  # held at its stop line: it contests nothing until its light changes
            # j holds the zone when inside it, or moving too fast to stop before it; a vehicle
            # standing at its edge holds nothing (such vehicles waiting on one another in a
            # ring would otherwise lock the junction for good)
            inside = front_j > zone.other_start_m
            moving = v[j] >= HELD_MPS and self._committed(j, front_j, v[j], zone.other_start_m)
            if inside or moving:
                contenders.append((j, True, 0.0))
            elif v[j] < HELD_MPS and self.held[j]:
                continue  # standing in a queue or giving way itself: not coming yet
            else:
                contenders.append((j, False, self._eta(j, front_j, v[j], zone.other_start_m)))
        self._zone_cache[key] = contenders
        return contenders

    def _crossing_obstacles(
        self, i: int, s: NDArray, v: NDArray
    ) -> list[tuple[float, float, Constraint, int]]:
        spec, path = self.vehicles[i], self.paths[i]
        front, rear = s[i] + 0.5 * spec.length_m, s[i] - 0.5 * spec.length_m
        obstacles: list[tuple[float, float, Constraint, int]] = []
        offset = len(self.vehicles)
        for k in self._active_pedestrians:
            ped, row = self.pedestrians[k], offset + k
            zone = self.network.crossing_zone(
                spec.movement_id, ped.crossing.crossing_id, ped.crossing.polygon
            )
            if zone is None or rear >= zone[1] or zone[0] - front > 40.0:
                continue
            if self._committed(i, front, v[i], zone[0]):
                continue
            position = self._ped_xy[k]
            near = (path.s_m >= zone[0]) & (path.s_m <= zone[1])
            distance = float(np.min(np.linalg.norm(path.points_m[near] - position, axis=1)))
            clear_i = self._eta(i, front, v[i], zone[1] + spec.length_m)
            if distance < PEDESTRIAN_REACH_M + ped.speed_mps * clear_i:
                obstacles.append((zone[0] - front + IDM_MIN_GAP_M - 1.0, 0.0, Constraint.VRU, row))
        return obstacles

    def _idm_free(self, i: int, s: NDArray, v: NDArray) -> float:
        front = s[i] + self.half_length[i]
        desired = min(self.vehicles[i].desired_speed_mps, self.paths[i].speed_limit_at(front))
        return self.max_accel[i] * (1.0 - (v[i] / max(desired, 0.1)) ** IDM_EXPONENT)

    def _idm(self, i: int, v: NDArray, gap: float, leader_speed: float, free: float) -> float:
        """IDM's acceleration behind an obstacle `gap` ahead moving at `leader_speed`, `free`
        being vehicle i's free-road term (`_idm_free`, worked out once a step)."""
        accel, brake = self.max_accel[i], self.comfort_brake[i]
        desired_gap = IDM_MIN_GAP_M + max(
            0.0,
            v[i] * IDM_HEADWAY_S + v[i] * (v[i] - leader_speed) / (2 * math.sqrt(accel * brake)),
        )
        return free - accel * (desired_gap / max(gap, 0.05)) ** 2

    def _advance_vehicles(
        self, step: int, s: NDArray, v: NDArray, state: NDArray, accel: NDArray, result: SimResult
    ) -> None:
        for i, spec in enumerate(self.vehicles):
            if state[i] != 1:
                continue
            a = min(max(float(accel[i]), -MAX_BRAKE_MPS2), self.max_accel[i])
            if v[i] + a * STEP_S < 0.0:
                a = -v[i] / STEP_S
            path = self.paths[i]
            front_before = s[i] + 0.5 * spec.length_m
            s[i] += v[i] * STEP_S + 0.5 * a * STEP_S**2
            v[i] += a * STEP_S
            accel[i] = a
            front_after = s[i] + 0.5 * spec.length_m
            if front_before < path.stop_s_m <= front_after:
                signal_id = path.movement.signal_id
                state_now = SignalState(int(result.signal_states[signal_id][step]))
                result.stop_line_state[spec.agent_id] = (step, state_now)
            if s[i] + 0.5 * spec.length_m >= path.length_m:  # leaves the map whole
                state[i] = 2
            x, y, heading = path.pose_at(s[i])
            self.vehicle_xy[i] = (x, y)
            self.vehicle_yaw[i] = heading

    # ------------------------------------------------------------------ pedestrians

    def _ped_position(self, k: int, s_value: float) -> NDArray[np.float64]:
        return np.array(self._walker_xy(k, s_value))

    def _walker_pose(self, k: int, s_value: float) -> tuple[float, float, float]:
        """Pedestrian k's (x, y, heading) at arclength `s_value`, clamped to its path: the
        values `geometry.interpolate_polyline` gives for one query, without its arrays (a
        few per walker and step); the heading is its leg's."""
        along, xs, ys = self.ped_s[k], self.ped_x[k], self.ped_y[k]
        s_clamped = min(max(s_value, 0.0), along[-1])
        segment = min(max(bisect.bisect_right(along, s_clamped) - 1, 0), len(xs) - 2)
        dx, dy = xs[segment + 1] - xs[segment], ys[segment + 1] - ys[segment]
        return (*self._walker_xy(k, s_value), float(np.arctan2(dy, dx)))

    def _road_clear(self, ped: PedestrianSpec, s: NDArray, v: NDArray, state: NDArray) -> bool:
        """No vehicle is on the crossing, and none is bearing down on it."""
        for j, spec in enumerate(self.vehicles):
            if state[j] != 1:
                continue
            zone = self.network.crossing_zone(
                spec.movement_id, ped.crossing.crossing_id, ped.crossing.polygon
            )
            if zone is None:
                continue
            half = 0.5 * spec.length_m
            front, rear = s[j] + half, s[j] - half
            if rear >= zone[1]:
                continue
            if front >= zone[0] or (v[j] > 1.0 and zone[0] - front < 2.0 + 3.0 * v[j]):
                return False
        return True

    def _advance_pedestrians(
        self, time_s: float, s: NDArray, v: NDArray, state: NDArray, states: dict[str, SignalState]
    ) -> None:
        offset = len(self.vehicles)
        for k, ped in enumerate(self.pedestrians):
            row = offset + k
            if state[row] != 1:
                continue
            phase = self._ped_state[k]
            speed = ped.speed_mps
            if (
                phase in ("approach", "waiting", "waiting_go")
                and s[row] + speed * STEP_S >= ped.enter_s_m
            ):
                signal = states.get(ped.crossing.signal_id) if ped.crossing.signal_id else None
                may_walk = ped.jaywalks or signal == SignalState.GREEN
                if may_walk and self._road_clear(ped, s, v, state):
                    phase = "crossing"
                else:
                    phase, speed = ("waiting_go" if may_walk else "waiting"), 0.0
                    s[row] = max(s[row], ped.enter_s_m - 0.05)
            if phase == "crossing" and self._vehicle_ahead_of(k, s, state):
                speed = 0.0
            if speed > 0.0 and self._walker_in_the_way(k, s[row] + speed * STEP_S, s, state):
                speed = 0.0
            s[row] += speed * STEP_S
            v[row] = speed
            if phase == "crossing" and s[row] >= ped.leave_s_m:
                phase = "leaving"
            if s[row] >= self.ped_s[k][-1]:
                state[row] = 2
            self._ped_state[k] = phase

    def _walker_xy(self, k: int, s_value: float) -> tuple[float, float]:
        """Pedestrian k's position at arclength `s_value` on its path (its few straight legs),
        clamped to its ends."""
        along = self.ped_s[k]
        return _interp(s_value, along, self.ped_x[k]), _interp(s_value, along, self.ped_y[k])

    def _walker_in_the_way(self, k: int, s_next: float, s: NDArray, state: NDArray) -> bool:
        """Whether pedestrian k's next step would bring it within `WALKER_GAP_M` of a walker
        who came before it (an earlier one in the list: the earlier never waits for the later,
        so no two wait for each other): it queues behind at a kerb, or keeps behind a slower
        walker, instead of stepping into their box."""
        offset = len(self.vehicles)
        ax, ay = self._walker_xy(k, s_next)
        hx, hy = self._walker_xy(k, s[offset + k])
        for j in range(k):
            if state[offset + j] != 1:
                continue
            ox, oy = self._walker_xy(j, s[offset + j])
            gap = math.hypot(ax - ox, ay - oy)
            if gap < WALKER_GAP_M and gap < math.hypot(hx - ox, hy - oy):
                return True
        return False

    def _vehicle_ahead_of(self, k: int, s: NDArray, state: NDArray) -> bool:
        """Whether a vehicle body is within reach of the pedestrian's next metre."""
        if not self.vehicles:
            return False
        ahead = self._ped_position(k, s[len(self.vehicles) + k] + 1.2)
        alive = state[: len(self.vehicles)] == 1
        distance = np.linalg.norm(self.vehicle_xy - ahead, axis=1)
        return bool(np.any(alive & (distance < np.asarray(self.half_length) + 0.8)))

    # ------------------------------------------------------------------ recording

    def _record(
        self, step: int, s: NDArray, v: NDArray, state: NDArray, accel: NDArray, result: SimResult
    ) -> None:
        alive = np.flatnonzero(state[: len(self.vehicles)] == 1)
        result.x_m[alive, step] = self.vehicle_xy[alive, 0]
        result.y_m[alive, step] = self.vehicle_xy[alive, 1]
        result.yaw_rad[alive, step] = self.vehicle_yaw[alive]
        result.speed_mps[alive, step] = v[alive]
        result.accel_mps2[alive, step] = accel[alive]
        result.s_m[alive, step] = s[alive]
        result.valid[alive, step] = True
        offset = len(self.vehicles)
        for k in range(len(self.pedestrians)):
            row = offset + k
            if state[row] != 1:
                continue
            x, y, heading = self._walker_pose(k, s[row])
            result.x_m[row, step], result.y_m[row, step] = x, y
            result.yaw_rad[row, step] = heading
            result.speed_mps[row, step] = v[row]
            result.accel_mps2[row, step] = 0.0
            result.s_m[row, step] = s[row]
            result.valid[row, step] = True


def _interp(x: float, xp: list[float], fp: list[float]) -> float:
    """`float(np.interp(x, xp, fp))` for one value, to the same bits (numpy's steps: the ends
    held, a sample's own value at a sample, else the segment's slope times the offset from its
    start plus its start's value), without the arrays numpy makes per call."""
    last = len(xp) - 1
    if x > xp[last]:
        return float(fp[last])
    if x < xp[0]:
        return float(fp[0])
    if x == xp[last]:
        return float(fp[last])
    j = bisect.bisect_right(xp, x) - 1
    if xp[j] == x:
        return float(fp[j])
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    return float(slope * (x - xp[j]) + fp[j])
