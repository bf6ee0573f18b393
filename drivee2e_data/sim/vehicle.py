"""The closed-loop ego: a kinematic bicycle moved by controls, and the controllers that turn
planned waypoints into controls (a longitudinal PID on speed; laterally, pure pursuit of an aim
point on the plan: the wheel angle whose arc from the rear axle passes through the aim point).

Frames and units: world = the map's local ENU (metres, radians); the state's position is the
rear-axle centre, as the nuScenes ego frame; waypoints are `(N, 2)` in the ego frame at 2 Hz.
Limits are those the collected labels use (`sensors.ego_state`): full throttle 4 m/s^2, full
brake 8 m/s^2, wheel angle at most 0.6 rad, wheelbase 0.6 car lengths.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.ego_limits import (
    FULL_BRAKE_MPS2,
    FULL_THROTTLE_MPS2,
    MAX_STEER_RAD,
    WHEELBASE_SHARE,
)

STEP_S = 0.1  # 10 Hz
WAYPOINT_PERIOD_S = 0.5  # planners' waypoints are 2 Hz
MAX_SPEED_MPS = 25.0
MAX_STEER_RATE_RADPS = 1.2  # how fast the wheels turn, lock to lock in one second
ROLLING_RESISTANCE_MPS2 = 0.15  # the car coasts to a stop without throttle
STOP_SPEED_MPS = 0.4  # a planned speed below this is a stop: full hold brake
AIM_MIN_M = 3.0  # lateral aim point at least this far ahead, farther with speed
AIM_TIME_S = 0.9
# the wheel's angle rate damps the pure-pursuit command (normalised steer per rad/s of aim angle)
AIM_DAMPING_S = 0.03
DEFAULT_WHEELBASE_M = WHEELBASE_SHARE * 4.6  # a typical car's, when the caller names none


@dataclass(frozen=True)
class Control:
    """One step's controls: `steer` in [-1, 1] of the full wheel angle (positive turns left),
    `throttle` and `brake` in [0, 1]."""

    steer: float = 0.0
    throttle: float = 0.0
    brake: float = 0.0

    def clipped(self) -> Control:
        return Control(
            float(np.clip(self.steer, -1.0, 1.0)),
            float(np.clip(self.throttle, 0.0, 1.0)),
            float(np.clip(self.brake, 0.0, 1.0)),
        )


@dataclass(frozen=True)
class VehicleState:
    """The ego at one step: rear-axle position and heading in the world, speed along the
    heading, front-wheel angle and the last longitudinal acceleration and yaw rate."""

    x_m: float
    y_m: float
    yaw_rad: float
    speed_mps: float
    steer_rad: float = 0.0
    acceleration_mps2: float = 0.0
    yaw_rate_radps: float = 0.0

    @property
    def xy_m(self) -> NDArray[np.float64]:
        return np.array([self.x_m, self.y_m])


@dataclass(frozen=True)
class Bicycle:
    """Kinematic bicycle of a car `length_m` long (wheelbase 0.6 lengths)."""

    length_m: float
    width_m: float
    rear_axle_to_centre_m: float

    @property
    def wheelbase_m(self) -> float:
        return WHEELBASE_SHARE * self.length_m

    def step(self, state: VehicleState, control: Control, dt_s: float = STEP_S) -> VehicleState:
        """The state `dt_s` later under `control` (semi-implicit Euler, speed never negative)."""
        control = control.clipped()
        target_steer = control.steer * MAX_STEER_RAD
        max_change = MAX_STEER_RATE_RADPS * dt_s
        steer = state.steer_rad + float(
            np.clip(target_steer - state.steer_rad, -max_change, max_change)
        )
        acceleration = control.throttle * FULL_THROTTLE_MPS2 - control.brake * FULL_BRAKE_MPS2
        if state.speed_mps > 0.0:
            acceleration -= ROLLING_RESISTANCE_MPS2
        speed = float(np.clip(state.speed_mps + acceleration * dt_s, 0.0, MAX_SPEED_MPS))
        acceleration = (speed - state.speed_mps) / dt_s
        yaw_rate = speed * np.tan(steer) / self.wheelbase_m
        yaw = state.yaw_rad + yaw_rate * dt_s
        mean_yaw = state.yaw_rad + 0.5 * yaw_rate * dt_s
        return VehicleState(
            x_m=state.x_m + speed * np.cos(mean_yaw) * dt_s,
            y_m=state.y_m + speed * np.sin(mean_yaw) * dt_s,
            yaw_rad=float(yaw),
            speed_mps=speed,
            steer_rad=steer,
            acceleration_mps2=float(acceleration),
            yaw_rate_radps=float(yaw_rate),
        )

    def centre_xy_m(self, state: VehicleState) -> NDArray[np.float64]:
        """(2,) the box centre in the world (the state holds the rear axle)."""
        heading = np.array([np.cos(state.yaw_rad), np.sin(state.yaw_rad)])
        return state.xy_m + self.rear_axle_to_centre_m * heading


@dataclass
class PID:
    """A discrete PID with a clamped integral (anti-windup)."""

    kp: float
    ki: float
    kd: float
    integral_limit: float = 1.0
    integral: float = 0.0
    previous: float | None = None

    def __call__(self, error: float, dt_s: float = STEP_S) -> float:
        self.integral = float(
            np.clip(self.integral + error * dt_s, -self.integral_limit, self.integral_limit)
        )
        derivative = 0.0 if self.previous is None else (error - self.previous) / dt_s
        self.previous = error
        return self.kp * error + self.ki * self.integral + self.kd * derivative


@dataclass
class WaypointController:
    """Controls that follow 2 Hz ego-frame waypoints: the planned speed is the distance to the
    first waypoint over its 0.5 s (a stop when below `STOP_SPEED_MPS`); the aim point lies on
    the plan `max(AIM_MIN_M, AIM_TIME_S * speed)` ahead, and the wheels take the pure-pursuit
    angle to it, `atan(2 wheelbase sin(alpha) / distance)`, for the car's `wheelbase_m`.

    Pure pursuit holds an arc of any radius the wheels allow exactly; a gain on the aim angle
    alone (this controller's first form) steered half the angle a 5 m U-turn needs at walking
    pace and swung the car wide, into the kerb (docs/closedloop.md)."""

    wheelbase_m: float = DEFAULT_WHEELBASE_M
    longitudinal: PID = field(default_factory=lambda: PID(0.45, 0.15, 0.02, integral_limit=2.0))

    def control(self, waypoints_xy_m: NDArray[np.float64], state: VehicleState) -> Control:
        waypoints = np.asarray(waypoints_xy_m, np.float64).reshape(-1, 2)
        if len(waypoints) == 0 or not np.isfinite(waypoints).all():
            return Control(brake=1.0)
        planned_speed = float(np.hypot(*waypoints[0])) / WAYPOINT_PERIOD_S
        acceleration = self.longitudinal(planned_speed - state.speed_mps)
        if planned_speed < STOP_SPEED_MPS:
            throttle, brake = 0.0, 1.0
            self.longitudinal.integral = 0.0
        else:
            throttle = max(acceleration, 0.0)
            brake = max(-acceleration, 0.0) * FULL_THROTTLE_MPS2 / FULL_BRAKE_MPS2
        aim = aim_point(waypoints, max(AIM_MIN_M, AIM_TIME_S * state.speed_mps))
        distance = float(np.hypot(*aim))
        steer = 0.0
        if distance > 0.5 and planned_speed >= STOP_SPEED_MPS:
            angle = float(np.arctan2(aim[1], aim[0]))
            wheel_rad = float(np.arctan2(2.0 * self.wheelbase_m * np.sin(angle), distance))
            steer = wheel_rad / MAX_STEER_RAD
        return Control(steer, throttle, brake).clipped()


def aim_point(waypoints_xy_m: NDArray[np.float64], distance_m: float) -> NDArray[np.float64]:
    """(2,) the point `distance_m` along the polyline from the ego origin through the
    waypoints, extended past the last waypoint along its last direction."""
    points = np.vstack([np.zeros((1, 2)), waypoints_xy_m])
    segments = np.diff(points, axis=0)
    lengths = np.hypot(segments[:, 0], segments[:, 1])
    cumulative = np.concatenate([[0.0], np.cumsum(lengths)])
    if cumulative[-1] < 1e-6:
        return np.zeros(2)
    index = int(np.searchsorted(cumulative, distance_m, side="right")) - 1
    index = min(max(index, 0), len(segments) - 1)
    while lengths[index] < 1e-6 and index > 0:
        index -= 1
    direction = segments[index] / max(lengths[index], 1e-9)
    return points[index] + direction * (distance_m - cumulative[index])
