"""Staging one clip: pick an ego movement and arrival time that produce a wanted behaviour, add
the agents the behaviour needs, simulate, check what happened, and keep the clip collision-free.

The staged label is what the simulation shows the ego did (from its binding constraints and the
signal at its stop line), never only what was planned. Precedence when several apply:
UT > YLW > IPC > COV > STP > plain turn.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from drivee2e_data.collision import EXPERT_TRACKING_MARGIN_M, boxes_collide
from drivee2e_data.hdmap import TurnDirection
from drivee2e_data.scenario import AgentClass, SignalState, SubScenario
from drivee2e_data.sources.synthetic.layout import CROSSWALK_WIDTH_M, Layout, Movement
from drivee2e_data.sources.synthetic.paths import PathNetwork
from drivee2e_data.sources.synthetic.population import (
    background_pedestrians,
    background_vehicles,
    crossing_pedestrian,
    crosswalk_crossing,
    jaywalk_crossing,
    make_vehicle,
)
from drivee2e_data.sources.synthetic.signals import SignalPlan
from drivee2e_data.sources.synthetic.traffic import (
    STEP_S,
    Constraint,
    PedestrianSpec,
    SimResult,
    TrafficSimulation,
    VehicleSpec,
)

WARMUP_S = 30.0  # traffic runs this long before a clip may start, so the junction is busy
MIN_CLIP_S = 15.0
MAX_CLIP_S = 30.0
MAX_ATTEMPTS = 8
MAX_REPAIRS = 8
QUEUE_REACH_M = 40.0  # an ego stopped this close to a red stop line is stopping at red
MIN_BINDING_STEPS = 3
QUIET_TARGETS = (SubScenario.STR, SubScenario.LFT, SubScenario.RT, SubScenario.STP)
QUIET_WINDOW_S = 40.0  # walkers due this close to the ego's arrival stay away for quiet targets
IPC_GAP_S = 3.0  # a pedestrian in the ego's conflict zone this close in time is an interaction
COV_GAP_S = 2.5  # another vehicle in a shared conflict zone this close in time competes
EXIT_MARGIN_M = 5.0  # the ego is this far into its exit lane by the end of the clip  # a constraint must bind this many steps (0.3 s) to count as yielding

TURN_OF = {
    "STR": TurnDirection.STRAIGHT,
    "LFT": TurnDirection.LEFT,
    "RT": TurnDirection.RIGHT,
}


@dataclass(frozen=True)
class StagedClip:
    """A simulated clip: who was there, what the ego did, and the frames that form the clip."""

    result: SimResult
    vehicles: list[VehicleSpec]
    pedestrians: list[PedestrianSpec]
    ego_row: int
    first_step: int
    last_step: int
    observed: SubScenario
    target: SubScenario
    removed_agents: int


def _wanted_turn(target: SubScenario) -> tuple[TurnDirection, bool]:
    if target == SubScenario.UT_N:
        return TurnDirection.U_TURN, False
    if target == SubScenario.UT_AN:
        return TurnDirection.U_TURN, True
    if target == SubScenario.STP:
        return TurnDirection.STRAIGHT, False
    return TURN_OF[target.value.split("-")[-1]], False


def _arrival_windows(
    plan: SignalPlan, signal_id: str, target: SubScenario, start_s: float
) -> list[float]:
    """Sim times at which arriving at the stop line suits the target's signal needs."""
    times = np.arange(start_s, start_s + plan.cycle_s, 0.5)
    states = np.array([plan.states_at(t)[signal_id] for t in times])
    candidates = []
    for k, time_s in enumerate(times):
        ahead = states[k : k + 13]  # the next 6 s
        if target.category.value == "YLW":
            if states[k] == SignalState.YELLOW and k > 0 and states[k - 1] == SignalState.GREEN:
                candidates.append(time_s + 0.6)
        elif target == SubScenario.STP:
            # red now, green again in 6-14 s: a wait the clip can show, then the drive through
            later = states[k : k + 29]
            if (
                len(later) == 29
                and (later[:12] == SignalState.RED).all()
                and (later[12:] == SignalState.GREEN).any()
            ):
                candidates.append(time_s)
        elif len(ahead) == 13 and (ahead == SignalState.GREEN).all():
            candidates.append(time_s)
    return candidates


class StagingError(RuntimeError):
    """No attempt could stage a clip for the target on this site."""


def stage_clip(
    layout: Layout,
    network: PathNetwork,
    plan: SignalPlan,
    target: SubScenario,
    rng: np.random.Generator,
) -> StagedClip:
    """The first attempt whose simulation shows `target`; else the last attempt, labelled as seen."""
    last: StagedClip | None = None
    for _ in range(MAX_ATTEMPTS):
        attempt = _attempt(layout, network, plan, target, rng)
        if attempt is None:
            continue
        last = attempt
        if attempt.observed == target:
            return attempt
    if last is None:
        raise StagingError(
            f"could not stage any clip for {target.value} on {layout.intersection_map.map_id}"
        )
    return last


def _attempt(
    layout: Layout,
    network: PathNetwork,
    plan: SignalPlan,
    target: SubScenario,
    rng: np.random.Generator,
) -> StagedClip | None:
    turn, abnormal = _wanted_turn(target)
    options = [m for m in layout.movements if m.turn == turn and m.abnormal == abnormal]
    if target == SubScenario.COV_LFT:
        permissive = [m for m in options if m.signal_id.endswith("_through")]
        options = permissive or options
    if not options:
        return None
    movement = options[int(rng.integers(len(options)))]
    windows = _arrival_windows(plan, movement.signal_id, target, WARMUP_S + 12.0)
    if not windows:
        return None
    arrival_s = float(windows[int(rng.integers(len(windows)))])
    clip_start_s = arrival_s - float(rng.uniform(4.0, 8.0))
    horizon_s = clip_start_s + MAX_CLIP_S + 1.0

    ego_class = AgentClass.CAR if rng.random() < 0.8 else AgentClass.VAN
    if turn == TurnDirection.U_TURN:
        ego_class = AgentClass.CAR  # the loops are fitted to the largest car (layout)
    path = network.paths[movement.movement_id]
    ego = make_vehicle(
        "v9999", ego_class, movement, 0.0, rng, runs_yellow=target.category.value == "YLW"
    )
    ego_spawn = arrival_s - (path.stop_s_m - 0.5 * ego.length_m) / ego.desired_speed_mps
    ego = replace(ego, spawn_time_s=ego_spawn)

    vehicles = [
        v
        for v in background_vehicles(layout, horizon_s, rng)
        if not (
            network.paths[v.movement_id].lanes[0][0] == movement.from_lane
            and -20.0 < v.spawn_time_s - ego_spawn < 4.0
        )
    ]
    pedestrians = background_pedestrians(layout, horizon_s, rng)
    if target in QUIET_TARGETS:
        # A plain drive or a stop at red: no walker on the ego's crossings around its passage.
        pedestrians = [
            p
            for p in pedestrians
            if network.crossing_zone(
                movement.movement_id, p.crossing.crossing_id, p.crossing.polygon
            )
            is None
            or abs(p.spawn_time_s - arrival_s) > QUIET_WINDOW_S
        ]
    injected_vehicles, injected_pedestrians = _helpers(
        layout, network, plan, target, movement, arrival_s, ego, rng
    )
    vehicles = [*vehicles, *injected_vehicles, ego]
    pedestrians = [*pedestrians, *injected_pedestrians]
    protected = (
        {ego.agent_id}
        | {v.agent_id for v in injected_vehicles}
        | {p.agent_id for p in injected_pedestrians}
    )
    return _simulate_and_repair(
        network, plan, vehicles, pedestrians, protected, clip_start_s, horizon_s, target, rng
    )


def _helpers(
    layout: Layout,
    network: PathNetwork,
    plan: SignalPlan,
    target: SubScenario,
    movement: Movement,
    arrival_s: float,
    ego: VehicleSpec,
    rng: np.random.Generator,
) -> tuple[list[VehicleSpec], list[PedestrianSpec]]:
    """Agents added so the target behaviour happens: walkers, a jaywalker, a contesting vehicle."""
    category = target.category.value
    path = network.paths[movement.movement_id]
    if category == "IPC" and target != SubScenario.IPC_STR:
        arm = layout.arms[movement.to_arm]
        crossing = crosswalk_crossing(arm)
        zone = network.crossing_zone(movement.movement_id, crossing.crossing_id, crossing.polygon)
        reach_s = arrival_s + ((zone[0] if zone else path.exit_s_m) - path.stop_s_m) / 5.0
        walkers = []
        for k in range(int(rng.integers(2, 4))):
            kerb_time = reach_s - float(rng.uniform(1.5, 3.5)) - 0.8 * k
            walk = plan.states_at(kerb_time).get(crossing.signal_id or "") == SignalState.GREEN
            along = arm.junction_edge_m + 0.5 * CROSSWALK_WIDTH_M + float(rng.uniform(-1.2, 1.2))
            walkers.append(
                crossing_pedestrian(
                    f"p9{k:03d}",
                    arm,
                    along,
                    bool(rng.random() < 0.5),
                    kerb_time,
                    rng,
                    crossing,
                    jaywalks=not walk,
                )
            )
        return [], walkers
    if target == SubScenario.IPC_STR:
        arm = layout.arms[movement.to_arm]
        along = arm.stop_m + float(rng.uniform(10.0, 22.0))
        ego_time = (
            arrival_s + (path.exit_s_m - path.stop_s_m + along - arm.stop_m) / ego.desired_speed_mps
        )
        crossing = jaywalk_crossing(arm, along, "jaywalk_0")
        walker = crossing_pedestrian(
            "p9000", arm, along, True, ego_time - 4.5, rng, crossing, jaywalks=True
        )
        return [], [walker]
    if category == "COV":
        contenders = []
        for zone in network.zones[movement.movement_id]:
            other = network.paths[zone.other].movement
            if other.from_lane == movement.from_lane or other.abnormal:
                continue
            if target == SubScenario.COV_LFT and other.turn not in (
                TurnDirection.STRAIGHT,
                TurnDirection.RIGHT,
            ):
                continue  # the rival must outrank the left turner, who then has to yield
            if plan.states_at(arrival_s)[other.signal_id] != SignalState.GREEN:
                continue
            contenders.append((zone, other))
        if not contenders:
            return [], []
        zone, other = contenders[int(rng.integers(len(contenders)))]
        ego_at_zone = arrival_s + (zone.start_m - path.stop_s_m) / max(
            6.0, 0.6 * ego.desired_speed_mps
        )
        # A lower-ranked rival must already hold the zone; a higher-ranked one arrives just after.
        lead = 1.0 if target != SubScenario.COV_LFT else -0.5
        rival = make_vehicle("v9000", AgentClass.CAR, other, 0.0, rng)
        travel = (zone.other_start_m - 0.5 * rival.length_m) / rival.desired_speed_mps
        rival = replace(rival, spawn_time_s=ego_at_zone - lead - travel)
        return [rival], []
    return [], []


def _simulate_and_repair(
    network: PathNetwork,
    plan: SignalPlan,
    vehicles: list[VehicleSpec],
    pedestrians: list[PedestrianSpec],
    protected: set[str],
    clip_start_s: float,
    horizon_s: float,
    target: SubScenario,
    rng: np.random.Generator,
) -> StagedClip | None:
    removed = 0
    clip_length_s = float(rng.uniform(MIN_CLIP_S, MAX_CLIP_S))
    for _ in range(MAX_REPAIRS):
        result = TrafficSimulation(network, plan, vehicles, pedestrians, horizon_s).run()
        ego_row = len(vehicles) - 1
        first = round(clip_start_s / STEP_S)
        valid_after = np.flatnonzero(result.valid[ego_row, first:])
        if not result.valid[ego_row, first] or valid_after.size == 0:
            return None
        run_end = first + int(np.flatnonzero(np.diff(np.r_[valid_after, -5]) != 1)[0])
        last = min(first + round(clip_length_s / STEP_S), run_end)
        # The clip must show the ego through the junction: extend it until the ego is
        # EXIT_MARGIN_M into its exit lane, within the 30 s limit, or give up on this attempt.
        path = network.paths[vehicles[ego_row].movement_id]
        cleared = np.flatnonzero(
            result.s_m[ego_row, first : run_end + 1] >= path.exit_s_m + EXIT_MARGIN_M
        )
        if cleared.size == 0:
            return None
        last = max(last, first + int(cleared[0]))
        if (last - first) * STEP_S > MAX_CLIP_S:
            return None
        if (last - first) * STEP_S < MIN_CLIP_S:
            return None
        clash = first_overlap(result, vehicles, pedestrians, first, last, ego_row)
        if clash is None:
            observed = observe(result, network, vehicles, pedestrians, ego_row, first, last)
            return StagedClip(
                result, vehicles, pedestrians, ego_row, first, last, observed, target, removed
            )
        victim = _pick_victim(clash, result, vehicles, pedestrians, protected)
        if victim is None:
            return None
        vehicles = [v for v in vehicles if v.agent_id != victim]
        pedestrians = [p for p in pedestrians if p.agent_id != victim]
        removed += 1
    return None


def agent_box_sizes(vehicles: list[VehicleSpec], pedestrians: list[PedestrianSpec]) -> np.ndarray:
    """(A, 2) length and width per sim row."""
    sizes = [(v.length_m, v.width_m) for v in vehicles] + [p.size_m[:2] for p in pedestrians]
    return np.asarray(sizes, dtype=np.float64)


def first_overlap(
    result: SimResult,
    vehicles: list[VehicleSpec],
    pedestrians: list[PedestrianSpec],
    first: int,
    last: int,
    ego_row: int | None = None,
) -> tuple[int, int] | None:
    """Rows of the first pair of agents that collide in steps [first, last] by the definition
    the closed-loop rules use (`collision.boxes_collide`); the ego's box (row `ego_row`) is
    grown by `EXPERT_TRACKING_MARGIN_M`, the most its closed-loop expert strays from the path
    staged here. Pedestrians count too: two standing in each other's box at a kerb made one
    hide the other while its label said it was seen."""
    sizes = agent_box_sizes(vehicles, pedestrians)
    margin = np.zeros(len(sizes))
    if ego_row is not None:
        margin[ego_row] = EXPERT_TRACKING_MARGIN_M
    reach = 0.5 * np.hypot(sizes[:, 0], sizes[:, 1]) + np.sqrt(2.0) * margin
    for step in range(first, last + 1):
        rows = np.flatnonzero(result.valid[:, step])
        xy = np.stack([result.x_m[rows, step], result.y_m[rows, step]], axis=-1)
        distance = np.linalg.norm(xy[:, None] - xy[None, :], axis=-1)
        close = distance < reach[rows][:, None] + reach[rows][None, :]
        pair_i, pair_j = np.nonzero(np.triu(close, 1))
        pair_i, pair_j = rows[pair_i], rows[pair_j]
        if pair_i.size == 0:
            continue
        # the grown box goes first: the pair's margin is the larger of the two (0 or the ego's)
        grown_first = margin[pair_i] >= margin[pair_j]
        row_a = np.where(grown_first, pair_i, pair_j)
        row_b = np.where(grown_first, pair_j, pair_i)
        hits = np.flatnonzero(
            boxes_collide(
                np.stack([result.x_m[row_a, step], result.y_m[row_a, step]], -1),
                result.yaw_rad[row_a, step],
                sizes[row_a],
                np.stack([result.x_m[row_b, step], result.y_m[row_b, step]], -1),
                result.yaw_rad[row_b, step],
                sizes[row_b],
                margin_a_m=margin[row_a],
            )
        )
        if hits.size:
            return int(pair_i[hits[0]]), int(pair_j[hits[0]])
    return None


def _pick_victim(
    clash: tuple[int, int],
    result: SimResult,
    vehicles: list[VehicleSpec],
    pedestrians: list[PedestrianSpec],
    protected: set[str],
) -> str | None:
    """The agent to leave out: unprotected first, then the later one to arrive."""
    specs = {
        **{v.agent_id: v.spawn_time_s for v in vehicles},
        **{p.agent_id: p.spawn_time_s for p in pedestrians},
    }
    names = [result.agent_ids[row] for row in clash]
    free = [n for n in names if n not in protected]
    pool = free or [n for n in names if n != vehicles[-1].agent_id]
    if not pool:
        return None
    return max(pool, key=lambda n: (specs[n], n))


def observe(
    result: SimResult,
    network: PathNetwork,
    vehicles: list[VehicleSpec],
    pedestrians: list[PedestrianSpec],
    ego_row: int,
    first: int,
    last: int,
) -> SubScenario:
    """What the ego did in steps [first, last], as a sub-scenario."""
    ego = vehicles[ego_row]
    movement = network.paths[ego.movement_id].movement
    window = slice(first, last + 1)
    constraint = result.constraint[ego_row, window]
    other = result.constraint_other[ego_row, window]
    speed = result.speed_mps[ego_row, window]
    turn_name = {
        TurnDirection.STRAIGHT: "STR",
        TurnDirection.LEFT: "LFT",
        TurnDirection.RIGHT: "RT",
    }

    if movement.turn == TurnDirection.U_TURN:
        return SubScenario.UT_AN if movement.abnormal else SubScenario.UT_N
    crossing = result.stop_line_state.get(ego.agent_id)
    crossed_in_clip = crossing is not None and first <= crossing[0] <= last
    if (
        crossed_in_clip
        and crossing[1] == SignalState.YELLOW
        and movement.turn != TurnDirection.RIGHT
    ):
        return SubScenario(f"YLW-{turn_name[movement.turn]}")

    rider_rows = {k for k, v in enumerate(vehicles) if v.agent_class.is_vulnerable}
    yielded_vru = (
        int(np.sum(constraint == Constraint.VRU)) >= MIN_BINDING_STEPS
        or int(np.sum((constraint == Constraint.VEHICLE) & np.isin(other, list(rider_rows))))
        >= MIN_BINDING_STEPS
    )
    if (
        yielded_vru
        or _pedestrian_gap_s(result, network, vehicles, pedestrians, ego_row, window) < IPC_GAP_S
    ):
        return SubScenario(f"IPC-{turn_name[movement.turn]}")

    yielded_vehicle = int(np.sum(constraint == Constraint.VEHICLE)) >= MIN_BINDING_STEPS
    contested = _vehicle_gap_s(result, network, vehicles, ego_row, window) < COV_GAP_S
    if yielded_vehicle or contested:
        return SubScenario(f"COV-{turn_name[movement.turn]}")

    # Stopped before the line while the light is red: at the line, or queued behind others.
    path = network.paths[ego.movement_id]
    front = result.s_m[ego_row, window] + 0.5 * ego.length_m
    red = result.signal_states[movement.signal_id][window] == SignalState.RED
    waiting = (front < path.stop_s_m) & (path.stop_s_m - front < QUEUE_REACH_M)
    stopped_at_red = bool(np.any(red & waiting & (speed < 0.3)))
    if stopped_at_red:
        return SubScenario.STP
    return SubScenario(turn_name[movement.turn])


def _occupancy_gap_s(ego_frames: np.ndarray, other_frames: np.ndarray) -> float:
    """Time (s) between two sets of frames (0 when they share one)."""
    if ego_frames.size == 0 or other_frames.size == 0:
        return np.inf
    return float(np.min(np.abs(ego_frames[:, None] - other_frames[None, :])) * STEP_S)


def _body_in(
    result: SimResult, row: int, half_length: float, zone: tuple[float, float], window: slice
) -> np.ndarray:
    s = result.s_m[row, window]
    inside = (s + half_length >= zone[0]) & (s - half_length <= zone[1]) & result.valid[row, window]
    return np.flatnonzero(inside)


def _pedestrian_gap_s(
    result: SimResult,
    network: PathNetwork,
    vehicles: list[VehicleSpec],
    pedestrians: list[PedestrianSpec],
    ego_row: int,
    window: slice,
) -> float:
    """Post-encroachment time between the ego and any moving pedestrian at a crossing of its path."""
    ego = vehicles[ego_row]
    path = network.paths[ego.movement_id]
    best = np.inf
    for k, pedestrian in enumerate(pedestrians):
        row = len(vehicles) + k
        zone = network.crossing_zone(
            ego.movement_id, pedestrian.crossing.crossing_id, pedestrian.crossing.polygon
        )
        if zone is None:
            continue
        ego_frames = _body_in(result, ego_row, 0.5 * ego.length_m, zone, window)
        points = path.points_m[(path.s_m >= zone[0]) & (path.s_m <= zone[1])]
        xy = np.stack([result.x_m[row, window], result.y_m[row, window]], -1)
        near = np.min(
            np.linalg.norm(np.nan_to_num(xy, nan=1e9)[:, None] - points[None], axis=-1), axis=1
        )
        walking = (near < 2.5) & (result.speed_mps[row, window] > 0.3) & result.valid[row, window]
        best = min(best, _occupancy_gap_s(ego_frames, np.flatnonzero(walking)))
    return best


def _vehicle_gap_s(
    result: SimResult,
    network: PathNetwork,
    vehicles: list[VehicleSpec],
    ego_row: int,
    window: slice,
) -> float:
    """Post-encroachment time between the ego and any vehicle in a shared conflict zone."""
    ego = vehicles[ego_row]
    best = np.inf
    for zone in network.zones[ego.movement_id]:
        ego_frames = _body_in(
            result, ego_row, 0.5 * ego.length_m, (zone.start_m, zone.end_m), window
        )
        if ego_frames.size == 0:
            continue
        for row, other in enumerate(vehicles):
            if other.movement_id != zone.other or other.agent_class.is_vulnerable:
                continue
            other_frames = _body_in(
                result, row, 0.5 * other.length_m, (zone.other_start_m, zone.other_end_m), window
            )
            best = min(best, _occupancy_gap_s(ego_frames, other_frames))
    return best
