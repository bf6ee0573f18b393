"""How each agent's model moves, from its logged track: distance travelled (wheels turn by it,
people step by it), front-wheel angle from the path's curvature, braking from deceleration.

Pure functions over a `Track`: every frame's animation comes from the whole track at once, so
any frame is drawn the same whatever was drawn before it (random access, resumable collection).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.ego_limits import WHEELBASE_SHARE
from drivee2e_data.scenario import FRAME_PERIOD_NS, Track
from drivee2e_data.sim.models import Animation, ModelMesh

DT_S = FRAME_PERIOD_NS / 1e9
BRAKE_DECELERATION_MPS2 = 0.6  # brake lights show above this deceleration (coasting is ~0.3)
STOPPED_MPS = 0.3  # a vehicle that moved in the clip and stands now holds its brake
WALKING_MPS = 0.9  # full swing from this speed; a still pedestrian stands
SMOOTHING_FRAMES = 5  # speed and yaw rate are averaged over half a second (the logs are noisy)


@dataclass(frozen=True)
class TrackMotion:
    """Per frame `(T,)`: distance travelled (m, from frame 0; held over invalid frames), speed
    (m/s), front-wheel angle (rad, left positive) and whether the brake lights show."""

    distance_m: NDArray[np.float64]
    speed_mps: NDArray[np.float64]
    steer_rad: NDArray[np.float64]
    braking: NDArray[np.bool_]


def _smoothed(values: NDArray[np.float64]) -> NDArray[np.float64]:
    if len(values) < SMOOTHING_FRAMES:
        return values
    kernel = np.ones(SMOOTHING_FRAMES) / SMOOTHING_FRAMES
    padded = np.pad(values, SMOOTHING_FRAMES // 2, mode="edge")
    return np.convolve(padded, kernel, mode="valid")


def track_motion(track: Track) -> TrackMotion:
    """The motion of `track`, from its logged positions and headings."""
    valid = track.valid
    xy = np.column_stack([track.x_m, track.y_m])
    step = np.zeros(len(xy))
    both = valid[1:] & valid[:-1]
    step[1:][both] = np.hypot(*(xy[1:] - xy[:-1])[both].T)
    distance = np.cumsum(step)
    speed = _smoothed(step / DT_S)
    speed[1:] = np.where(both, speed[1:], 0.0)
    yaw = np.unwrap(np.where(valid, track.yaw_rad, 0.0))
    yaw_rate = _smoothed(np.gradient(yaw) / DT_S) if len(yaw) > 1 else np.zeros(len(yaw))
    length = float(np.median(track.length_m[valid])) if valid.any() else 4.0
    curvature = np.where(speed > 0.5, yaw_rate / np.maximum(speed, 0.5), 0.0)
    steer = np.arctan(WHEELBASE_SHARE * length * curvature)
    deceleration = -np.gradient(speed) / DT_S if len(speed) > 1 else np.zeros(len(speed))
    moved = bool(distance[-1] > 2.0) if len(distance) else False
    braking = (_smoothed(deceleration) > BRAKE_DECELERATION_MPS2) | (moved & (speed < STOPPED_MPS))
    return TrackMotion(distance, speed, steer, braking & valid)


def animation_at(
    motion: TrackMotion, frame: int, model: ModelMesh, headlights: bool, walks: bool
) -> Animation:
    """The model's pose inputs at `frame`: wheels turned by distance / radius, people stepped by
    distance / stride."""
    distance = float(motion.distance_m[frame])
    wheel = distance / model.wheel_radius_m if model.wheel_radius_m > 0 else 0.0
    walk_phase = 2 * np.pi * distance / model.stride_m if model.stride_m > 0 else 0.0
    amount = float(np.clip(motion.speed_mps[frame] / WALKING_MPS, 0.0, 1.0)) if walks else 0.0
    return Animation(
        wheel_angle_rad=wheel,
        steer_rad=float(motion.steer_rad[frame]),
        walk_phase_rad=float(walk_phase),
        walk_amount=amount,
        brake=bool(motion.braking[frame]),
        headlights=headlights,
    )
