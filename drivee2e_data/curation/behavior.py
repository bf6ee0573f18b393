"""Label an ego's behaviour (8 categories, 14 sub-scenarios) from its track, the other tracks,
the signal timelines and the map, with no knowledge of how the clip was made.

- Turn: the net heading change of the ego's drive (U-turn beyond 150 degrees, left or right
  beyond 45); a U-turn is normal when a mapped U-turn lane carries it, abnormal otherwise.
- Stop line and signal: the stop line at the end of the lane the ego approaches on, and the
  signal of the junction lane it then drives (or of its approach lane).
- YLW: the ego's front crosses that stop line on yellow (left or straight).
- STP: the ego stands still at red, before its stop line and within `QUEUE_REACH_M` of it.
- IPC: a pedestrian or rider crossing the ego's path reaches a point of it within
  `IPC_GAP_S` of the ego (post-encroachment time), or the ego gives way to one there.
- COV: another vehicle crossing or merging into the ego's path does the same within
  `COV_GAP_S`, or the ego gives way to one (slows near the point the other then takes first).
Precedence: UT > YLW > IPC > COV > STP > plain turn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from numpy.typing import NDArray

from drivee2e_data.binding import front_bumper
from drivee2e_data.geometry import wrap_angle
from drivee2e_data.hdmap import IntersectionMap, StopLine, TurnDirection
from drivee2e_data.scenario import AgentClass, Scenario, SignalState, SubScenario, Track

FRAME_S = 0.1
U_TURN_RAD = np.deg2rad(150)  # a net heading change beyond this is a U-turn
TURN_RAD = np.deg2rad(45)  # beyond this a left or right turn
MOVING_MPS = 0.5  # the ego's heading counts only while it moves
LANE_MATCH_M = 1.8  # the ego is on a lane when this close to its centre line and aligned
QUEUE_REACH_M = 40.0  # stopped this close before a red stop line is stopping at red
STANDSTILL_MPS = 0.3
VEHICLE_CONFLICT_M = 3.2  # centres of two vehicles closer than this on the ego's path could touch
PEDESTRIAN_CONFLICT_M = 2.5  # a pedestrian or rider this close to the ego's path is in its way
IPC_GAP_S = 3.0  # post-encroachment time below which a pedestrian or rider interacts
COV_GAP_S = 2.5  # post-encroachment time below which a vehicle competes with the ego
CROSSING_RAD = np.deg2rad(30)  # a vehicle heading closer than this to the ego's is following it
YIELD_MPS = 4.0  # slower than this before a conflict point is giving way
YIELD_REACH_M = 25.0  # ...when within this distance of the point
YIELD_WINDOW_S = 6.0  # ...in the seconds before the other agent took the point
VRU_CLASSES = (
    AgentClass.PEDESTRIAN,
    AgentClass.CYCLIST,
    AgentClass.TRICYCLIST,
    AgentClass.MOTORCYCLIST,
)


@dataclass(frozen=True)
class Evidence:
    """What the labeller saw, for reports and debugging."""

    turn: TurnDirection
    abnormal_u_turn: bool
    stop_line: str | None
    signal: str | None
    crossing_frame: int | None
    crossing_state: SignalState | None
    stopped_at_red: bool
    vru_gap_s: float
    vehicle_gap_s: float
    yielded_to_vru: bool
    yielded_to_vehicle: bool


def _ego_arrays(ego: Track) -> tuple[NDArray, NDArray, NDArray]:
    frames = np.flatnonzero(ego.valid)
    return frames, ego.xy_m[frames], ego.speed_mps[frames]


def net_heading_change(ego: Track) -> float:
    """Unwrapped heading change over the frames where the ego moves (radians, CCW positive)."""
    frames, _, speed = _ego_arrays(ego)
    moving = frames[speed > MOVING_MPS]
    if moving.size < 2:
        return 0.0
    yaw = np.unwrap(ego.yaw_rad[moving])
    return float(yaw[-1] - yaw[0])


def turn_of(ego: Track) -> TurnDirection:
    change = net_heading_change(ego)
    if abs(change) > U_TURN_RAD:
        return TurnDirection.U_TURN
    if change > TURN_RAD:
        return TurnDirection.LEFT
    if change < -TURN_RAD:
        return TurnDirection.RIGHT
    return TurnDirection.STRAIGHT


def lanes_driven(ego: Track, intersection_map: IntersectionMap) -> list[str]:
    """Lanes the ego drives on, in order, matched by distance and heading."""
    frames, xy, _ = _ego_arrays(ego)
    sequence: list[str] = []
    lines = {
        lane.lane_id: shapely.LineString(lane.centerline_m[:, :2])
        for lane in intersection_map.lanes
    }
    points = shapely.points(xy[:, 0], xy[:, 1])
    distance = {lane_id: shapely.distance(line, points) for lane_id, line in lines.items()}
    by_id = {lane.lane_id: lane for lane in intersection_map.lanes}
    for n, frame in enumerate(frames):
        best, best_distance = None, LANE_MATCH_M
        for lane_id, values in distance.items():
            if values[n] < best_distance:
                heading = by_id[lane_id].heading_at(*xy[n])
                if abs(wrap_angle(ego.yaw_rad[frame] - heading)) < np.deg2rad(60):
                    best, best_distance = lane_id, values[n]
        if best is not None and (not sequence or sequence[-1] != best):
            sequence.append(best)
    return sequence


def _stop_line_and_signal(
    ego: Track, intersection_map: IntersectionMap, driven: list[str], turn: TurnDirection
) -> tuple[StopLine | None, str | None]:
    by_id = {lane.lane_id: lane for lane in intersection_map.lanes}
    approach = [lane_id for lane_id in driven if not by_id[lane_id].is_intersection]
    stop_line = None
    for lane_id in approach:
        stop_line = next((s for s in intersection_map.stop_lines if lane_id in s.lane_ids), None)
        if stop_line is not None:
            approach_lane = lane_id
            break
    if stop_line is None:
        return None, None
    junction = [lane_id for lane_id in driven if by_id[lane_id].is_intersection]
    candidates = [by_id[j] for j in junction if by_id[j].signal_id]
    if not candidates:
        successors = [by_id[s] for s in by_id[approach_lane].successors if s in by_id]
        matching = [lane for lane in successors if lane.signal_id and lane.turn_direction == turn]
        candidates = matching or [lane for lane in successors if lane.signal_id]
    if not candidates and by_id[approach_lane].signal_id:
        candidates = [by_id[approach_lane]]
    return stop_line, (candidates[0].signal_id if candidates else None)


def _front(ego: Track) -> NDArray:
    return front_bumper(ego.xy_m, ego.yaw_rad, ego.length_m)


def _crossing_frame(ego: Track, stop_line: StopLine) -> int | None:
    line = shapely.LineString(stop_line.line_m[:, :2])
    front = _front(ego)
    for k in range(ego.num_frames - 1):
        if (
            ego.valid[k]
            and ego.valid[k + 1]
            and shapely.LineString(front[k : k + 2]).intersects(line)
        ):
            return k + 1
    return None


def _distance_before_line(ego: Track, stop_line: StopLine) -> NDArray:
    """Signed distance (m) of the ego's front before the stop line along the ego's heading."""
    middle = stop_line.line_m[:, :2].mean(axis=0)
    front = _front(ego)
    direction = np.stack([np.cos(ego.yaw_rad), np.sin(ego.yaw_rad)], -1)
    return np.sum((middle - front) * direction, axis=-1)


def _conflicts(ego: Track, other: Track, crossing_only: bool) -> tuple[NDArray, NDArray]:
    """Frame pairs (ego frame, other frame) at which both occupy the same point of the ego's path."""
    ego_frames = np.flatnonzero(ego.valid)
    other_frames = np.flatnonzero(other.valid)
    if other_frames.size == 0:
        return np.zeros(0, int), np.zeros(0, int)
    a, b = ego.xy_m[ego_frames], other.xy_m[other_frames]
    distance = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)
    radius = PEDESTRIAN_CONFLICT_M if other.agent_class in VRU_CLASSES else VEHICLE_CONFLICT_M
    close = distance < radius
    i, j = np.nonzero(close)
    moving = other.speed_mps[other_frames[j]] > MOVING_MPS
    i, j = i[moving], j[moving]
    if crossing_only and i.size:
        angle = np.abs(wrap_angle(ego.yaw_rad[ego_frames[i]] - other.yaw_rad[other_frames[j]]))
        keep = (angle > CROSSING_RAD) & (angle < np.pi - CROSSING_RAD)
        i, j = i[keep], j[keep]
    return ego_frames[i], other_frames[j]


def _same_stream(ego_lanes: list[str], other: Track, intersection_map: IntersectionMap) -> bool:
    """Whether `other` comes from the ego's own approach lane (a leader or follower)."""
    other_lanes = lanes_driven(other, intersection_map)
    return bool(ego_lanes and other_lanes and other_lanes[0] in ego_lanes[:1])


def _interaction(ego: Track, other: Track, crossing_only: bool, red: NDArray) -> tuple[float, bool]:
    """Post-encroachment time (s) with `other`, and whether the ego yielded to it: slowed
    below `YIELD_MPS` within `YIELD_REACH_M` before a conflict point that `other` then took
    first, within `YIELD_WINDOW_S`, while its light was not red."""
    ego_at, other_at = _conflicts(ego, other, crossing_only)
    if ego_at.size == 0:
        return np.inf, False
    gap = float(np.min(np.abs(ego_at - other_at)) * FRAME_S)
    yielded = False
    window = round(YIELD_WINDOW_S / FRAME_S)
    for e, o in zip(ego_at[other_at < ego_at], other_at[other_at < ego_at], strict=True):
        frames = np.arange(max(o - window, 0), o + 1)
        frames = frames[ego.valid[frames] & (frames < e)]
        if frames.size == 0:
            continue
        point = ego.xy_m[e]
        near = np.linalg.norm(ego.xy_m[frames] - point, axis=1) < YIELD_REACH_M
        slow = ego.speed_mps[frames] < YIELD_MPS
        if np.any(near & slow & ~red[frames]):
            yielded = True
            break
    return gap, yielded


def gather_evidence(
    scenario: Scenario, intersection_map: IntersectionMap, ego_id: str | None = None
) -> Evidence:
    ego = scenario.track(ego_id or scenario.ego_id or "")
    turn = turn_of(ego)
    driven = lanes_driven(ego, intersection_map)
    abnormal = False
    if turn == TurnDirection.U_TURN:
        abnormal = not _u_turn_is_mapped(driven, intersection_map)
    stop_line, signal_id = _stop_line_and_signal(ego, intersection_map, driven, turn)
    crossing = crossing_state = None
    stopped_at_red = False
    known = {s.signal_id for s in scenario.signals}
    if stop_line is not None:
        crossing = _crossing_frame(ego, stop_line)
        if signal_id in known:
            states = scenario.signal(signal_id).states
            if crossing is not None:
                crossing_state = SignalState(int(states[crossing]))
            before = _distance_before_line(ego, stop_line)
            waiting = (
                ego.valid
                & (before > -0.5)
                & (before < QUEUE_REACH_M)
                & (ego.speed_mps < STANDSTILL_MPS)
            )
            if crossing is not None:
                waiting[crossing:] = False
            stopped_at_red = bool(np.any(waiting & (states == SignalState.RED)))
    red = np.zeros(ego.num_frames, bool)
    if signal_id in known:
        red = scenario.signal(signal_id).states == SignalState.RED
    vru_gap = vehicle_gap = np.inf
    yielded_vru = yielded_vehicle = False
    for other in scenario.tracks:
        if other.track_id == ego.track_id:
            continue
        if other.agent_class in VRU_CLASSES:
            gap, yielded = _interaction(ego, other, other.agent_class != AgentClass.PEDESTRIAN, red)
            vru_gap, yielded_vru = min(vru_gap, gap), yielded_vru or yielded
        else:
            gap, yielded = _interaction(ego, other, True, red)
            if np.isinf(gap) and not yielded:
                # merges meet the ego at a shallow angle: count any vehicle not from its lane
                gap, yielded = _interaction(ego, other, False, red)
                if (np.isfinite(gap) or yielded) and _same_stream(driven, other, intersection_map):
                    gap, yielded = np.inf, False
            vehicle_gap, yielded_vehicle = min(vehicle_gap, gap), yielded_vehicle or yielded
    return Evidence(turn, abnormal, None if stop_line is None else stop_line.stop_line_id, signal_id, crossing,
                    crossing_state, stopped_at_red, vru_gap, vehicle_gap, yielded_vru, yielded_vehicle)  # fmt: skip


def _u_turn_is_mapped(driven: list[str], intersection_map: IntersectionMap) -> bool:
    """A U-turn is normal when it starts from a lane that the map lets U-turn (or drives a
    mapped U-turn lane); a U-turn from any other lane is abnormal."""
    by_id = {lane.lane_id: lane for lane in intersection_map.lanes}
    for lane_id in driven:
        lane = by_id[lane_id]
        if lane.turn_direction == TurnDirection.U_TURN:
            return True
        if not lane.is_intersection:
            successors = [by_id[s] for s in lane.successors if s in by_id]
            return any(s.turn_direction == TurnDirection.U_TURN for s in successors)
    return False


TURN_NAME = {TurnDirection.STRAIGHT: "STR", TurnDirection.LEFT: "LFT", TurnDirection.RIGHT: "RT"}


def label_from(evidence: Evidence) -> SubScenario:
    """The sub-scenario the evidence shows, by the precedence UT > YLW > IPC > COV > STP > plain."""
    if evidence.turn == TurnDirection.U_TURN:
        return SubScenario.UT_AN if evidence.abnormal_u_turn else SubScenario.UT_N
    name = TURN_NAME[evidence.turn]
    if evidence.crossing_state == SignalState.YELLOW and evidence.turn != TurnDirection.RIGHT:
        return SubScenario(f"YLW-{name}")
    if evidence.vru_gap_s < IPC_GAP_S or evidence.yielded_to_vru:
        return SubScenario(f"IPC-{name}")
    if evidence.vehicle_gap_s < COV_GAP_S or evidence.yielded_to_vehicle:
        return SubScenario(f"COV-{name}")
    if evidence.stopped_at_red:
        return SubScenario.STP
    return SubScenario(name)


def label(
    scenario: Scenario, intersection_map: IntersectionMap, ego_id: str | None = None
) -> SubScenario:
    """The behaviour of the scenario's ego (or of `ego_id`)."""
    return label_from(gather_evidence(scenario, intersection_map, ego_id))
