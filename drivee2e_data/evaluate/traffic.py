"""The other agents during an episode: each at its logged pose (log replay), or, with
`reactive=True`, motor vehicles driving their logged path with IDM speed control so they brake
for the ego (and for reactive vehicles that fell behind their log).

An agent is shown while its track is valid at the step; after the log's last frame every agent
is gone (no log says where they went). World frame; poses are box centres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.geometry import wrap_angle
from drivee2e_data.scenario import Scenario, Track
from drivee2e_data.sim.actors import choose_blueprint

STEP_S = 0.1
# IDM (Treiber et al.) for passenger traffic at an intersection
IDM_MAX_ACCELERATION_MPS2 = 1.5
IDM_COMFORT_BRAKE_MPS2 = 2.0
IDM_TIME_HEADWAY_S = 1.2
IDM_MIN_GAP_M = 2.0
MAX_BRAKE_MPS2 = 6.0
LEADER_LOOKAHEAD_M = 40.0
CORRIDOR_MARGIN_M = 0.3  # the ego blocks a path when it overlaps the path's width plus this
BEHIND_LOG_M = 0.5  # a reactive vehicle this far behind its log is a leader for others


@dataclass(frozen=True)
class AgentPose:
    """One shown agent at one step: box centre, heading, the blueprint's box, its speed."""

    track_id: str
    x_m: float
    y_m: float
    z_m: float  # box centre height in the world
    yaw_rad: float
    length_m: float
    width_m: float
    height_m: float
    speed_mps: float


@dataclass
class _Follower:
    """A reactive vehicle's progress along its own logged path."""

    track: Track
    s_log_m: NDArray[np.float64]  # (T,) logged arclength per frame, NaN where invalid
    path_s_m: NDArray[np.float64]  # (K,) arclength of the strictly advancing path points
    path_xy_m: NDArray[np.float64]  # (K, 2)
    path_yaw_rad: NDArray[np.float64]  # (K,) unwrapped
    path_z_m: NDArray[np.float64]
    s_m: float = float("nan")
    speed_mps: float = 0.0


class Traffic:
    """Poses of every agent but the ego, step by step."""

    def __init__(
        self, scenario: Scenario, reactive: bool = False, removed: frozenset[str] = frozenset()
    ) -> None:
        self.scenario, self.reactive = scenario, reactive
        self.tracks = [
            t
            for t in scenario.tracks
            if t.track_id != scenario.ego_id and t.track_id not in removed
        ]
        self.sizes = {t.track_id: choose_blueprint(t).size_m for t in self.tracks}
        self.classes = {t.track_id: t.agent_class for t in self.tracks}
        self.followers = {
            t.track_id: _follower(t)
            for t in self.tracks
            if reactive and t.agent_class.is_motor_vehicle and int(t.valid.sum()) >= 2
        }

    @property
    def ego_blind(self) -> bool:
        """Whether the poses ignore the ego (every agent on its log: none reacts), so that a
        step's can be had before the ego drives there."""
        return not self.followers

    def poses(
        self,
        step: int,
        ego_centre_xy_m: NDArray[np.float64] | None = None,
        ego_yaw_rad: float = 0.0,
        ego_speed_mps: float = 0.0,
        ego_size_m: tuple[float, float] = (4.6, 1.85),
    ) -> list[AgentPose]:
        """The shown agents at `step`; reactive vehicles first advance one step (call once per
        step, in order) given where the ego is."""
        if step >= self.scenario.num_frames:
            return []
        if self.followers:
            self._advance(step, ego_centre_xy_m, ego_yaw_rad, ego_speed_mps, ego_size_m)
        shown = []
        for track in self.tracks:
            if not track.valid[step]:
                continue
            length, width, height = self.sizes[track.track_id]
            follower = self.followers.get(track.track_id)
            ground = float(track.z_m[step] - 0.5 * track.height_m[step])
            if follower is not None and np.isfinite(follower.s_m):
                x, y, yaw, z = _along(follower, follower.s_m)
                speed = follower.speed_mps
                ground = z - 0.5 * float(track.height_m[step])
            else:
                x, y, yaw = track.x_m[step], track.y_m[step], track.yaw_rad[step]
                speed = float(np.hypot(track.vx_mps[step], track.vy_mps[step]))
            shown.append(
                AgentPose(
                    track.track_id,
                    float(x),
                    float(y),
                    ground + 0.5 * height,
                    float(yaw),
                    length,
                    width,
                    height,
                    float(speed),
                )
            )
        return shown

    def _advance(
        self,
        step: int,
        ego_xy: NDArray[np.float64] | None,
        ego_yaw: float,
        ego_speed: float,
        ego_size: tuple[float, float],
    ) -> None:
        # leaders: the ego and reactive vehicles behind their log (vehicles on their log keep
        # the gaps the log has among themselves)
        leaders: list[tuple[NDArray[np.float64], float, float, float, float, str]] = []
        if ego_xy is not None:
            leaders.append((np.asarray(ego_xy), ego_yaw, ego_speed, *ego_size, ""))
        for track_id, f in self.followers.items():
            if np.isfinite(f.s_m) and f.s_log_m[step - 1 if step else 0] - f.s_m > BEHIND_LOG_M:
                x, y, yaw, _ = _along(f, f.s_m)
                length, width, _ = self.sizes[track_id]
                leaders.append((np.array([x, y]), yaw, f.speed_mps, length, width, track_id))
        for track_id, f in self.followers.items():
            if not f.track.valid[step]:
                f.s_m = float("nan")
                continue
            if not np.isfinite(f.s_m):  # appears: starts on its log
                f.s_m = float(f.s_log_m[step])
                f.speed_mps = float(np.hypot(f.track.vx_mps[step], f.track.vy_mps[step]))
                continue
            # the speed that puts it back on its log at this step, within its limits
            wanted = (float(f.s_log_m[step]) - f.s_m) / STEP_S
            acceleration = float(
                np.clip((wanted - f.speed_mps) / STEP_S, -MAX_BRAKE_MPS2, IDM_MAX_ACCELERATION_MPS2 * 2)
            )  # fmt: skip
            length, width, _ = self.sizes[track_id]
            gap, leader_speed = _nearest_leader(f, length, width, leaders, track_id)
            if gap is not None:
                acceleration = min(acceleration, _idm(f.speed_mps, leader_speed, gap))
            acceleration = max(acceleration, -MAX_BRAKE_MPS2)
            f.speed_mps = max(0.0, f.speed_mps + acceleration * STEP_S)
            f.s_m = min(f.s_m + f.speed_mps * STEP_S, float(f.path_s_m[-1]))


def _follower(track: Track) -> _Follower:
    valid = np.flatnonzero(track.valid)
    xy = track.xy_m[valid]
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    s_log = np.full(track.num_frames, np.nan)
    s_log[valid] = s
    advancing = np.concatenate([[True], np.diff(s) > 1e-3])
    keep = valid[advancing]
    path_s = s[advancing]
    if len(path_s) < 2:  # a parked vehicle: a path of one point, padded
        path_s = np.array([0.0, 1e-3])
        keep = np.array([valid[0], valid[0]])
    return _Follower(
        track=track,
        s_log_m=s_log,
        path_s_m=path_s,
        path_xy_m=track.xy_m[keep],
        path_yaw_rad=np.unwrap(track.yaw_rad[keep]),
        path_z_m=track.z_m[keep],
    )


def _along(f: _Follower, s_m: float) -> tuple[float, float, float, float]:
    x = float(np.interp(s_m, f.path_s_m, f.path_xy_m[:, 0]))
    y = float(np.interp(s_m, f.path_s_m, f.path_xy_m[:, 1]))
    yaw = float(np.interp(s_m, f.path_s_m, f.path_yaw_rad))
    z = float(np.interp(s_m, f.path_s_m, f.path_z_m))
    return x, y, yaw, z


def _nearest_leader(
    f: _Follower,
    length_m: float,
    width_m: float,
    leaders: list[tuple[NDArray[np.float64], float, float, float, float, str]],
    track_id: str,
) -> tuple[float | None, float]:
    """Bumper-to-bumper gap to the nearest leader on this vehicle's path ahead, and its speed
    along the path."""
    ahead = (f.path_s_m > f.s_m - 1.0) & (f.path_s_m < f.s_m + LEADER_LOOKAHEAD_M)
    if not ahead.any():
        return None, 0.0
    points, s_points = f.path_xy_m[ahead], f.path_s_m[ahead]
    if len(points) < 2:
        return None, 0.0
    best_gap, best_speed = None, 0.0
    for xy, yaw, speed, other_length, other_width, other_id in leaders:
        if other_id == track_id:
            continue
        distance = np.hypot(*(points - xy).T)
        nearest = int(np.argmin(distance))
        if distance[nearest] > 0.5 * (width_m + other_width) + CORRIDOR_MARGIN_M:
            continue
        s_other = float(s_points[nearest])
        gap = s_other - f.s_m - 0.5 * (length_m + other_length)
        if s_other <= f.s_m:
            continue
        heading = float(
            np.arctan2(
                *(points[min(nearest + 1, len(points) - 1)] - points[max(nearest - 1, 0)])[::-1]
            )
        )
        along = speed * float(np.cos(wrap_angle(yaw - heading)))  # fmt: skip
        if best_gap is None or gap < best_gap:
            best_gap, best_speed = max(gap, 0.1), max(along, 0.0)
    return best_gap, best_speed


def _idm(speed_mps: float, leader_speed_mps: float, gap_m: float) -> float:
    """IDM's acceleration behind a leader (the free-road term is the log's own speed, applied by
    the caller, so only the interaction term is used here)."""
    closing = speed_mps - leader_speed_mps
    desired = IDM_MIN_GAP_M + max(
        0.0,
        speed_mps * IDM_TIME_HEADWAY_S
        + speed_mps * closing / (2.0 * np.sqrt(IDM_MAX_ACCELERATION_MPS2 * IDM_COMFORT_BRAKE_MPS2)),
    )
    return IDM_MAX_ACCELERATION_MPS2 * (1.0 - (desired / gap_m) ** 2)
