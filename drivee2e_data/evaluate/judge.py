"""The route's rules at each step of a closed-loop episode (`StepJudge`): the collisions (each
partner once), red lights crossed (each stop line once), the metres driven outside the route's
lanes and off the road, and the ends of the route (completed, deviated, blocked, timed out),
counted from the ego's step and the other agents where that step left them. What the judge
decides ends an episode or scores it; it never changes what the agent observes next, so an
episode may judge a step while its agent thinks about the next (`evaluate/episode.py`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.evaluate.traffic import STEP_S, AgentPose, Traffic
from drivee2e_data.metrics import closedloop as rules
from drivee2e_data.metrics.closedloop import Event, Infraction, MapRules, Obstacle, RouteProgress
from drivee2e_data.scenario import Scenario, SignalState
from drivee2e_data.sim.vehicle import Bicycle, VehicleState


def signals_at(scenario: Scenario, step: int) -> dict[str, SignalState]:
    """Each signal's state at `step`; after the log, the lights keep their last state."""
    frame = min(step, scenario.num_frames - 1)
    return {s.signal_id: s.state_at(frame) for s in scenario.signals}


@dataclass
class StepJudge:
    """The rules of one episode, step by step (`judge`), and what they counted: its events,
    the partners hit and red lines crossed, the metres driven, outside the route's lanes and
    off the road (and the first step of each), the steps stopped in a row. Its limits in
    steps: the route's timeout (`max_steps`), the scenario's (`late_step`) and how long the
    ego may stand (`blocked_steps`; `for_episode` sets all three from the clip)."""

    scenario: Scenario
    rules: MapRules
    traffic: Traffic
    bicycle: Bicycle
    progress: RouteProgress
    max_steps: int
    late_step: float
    blocked_steps: int
    events: list[Event] = field(default_factory=list)
    hit_partners: set[str] = field(default_factory=set)
    red_lines: set[str] = field(default_factory=set)
    driven_m: float = 0.0
    outside_m: float = 0.0
    off_road_m: float = 0.0
    outside_first: int = -1
    off_road_first: int = -1
    stopped: int = 0

    @classmethod
    def for_episode(
        cls,
        scenario: Scenario,
        map_rules: MapRules,
        traffic: Traffic,
        bicycle: Bicycle,
        progress: RouteProgress,
        logged_speed_mps: NDArray[np.float64],
    ) -> StepJudge:
        """The judge of a clip whose logged ego drove at `logged_speed_mps` `(T,)`: its
        timeouts scaled to the clip's length, its patience to the log's longest stop
        (`metrics/closedloop.py`'s thresholds)."""
        frames = scenario.num_frames
        return cls(
            scenario, map_rules, traffic, bicycle, progress,
            max_steps=math.ceil(
                (frames - 1) * rules.ROUTE_TIMEOUT_FACTOR + rules.ROUTE_TIMEOUT_MARGIN_S / STEP_S
            ),
            late_step=(frames - 1) * (1 + rules.SCENARIO_TIMEOUT_SHARE)
            + rules.SCENARIO_TIMEOUT_MARGIN_S / STEP_S,
            blocked_steps=round(
                (rules.longest_stop_s(logged_speed_mps) + rules.BLOCKED_MARGIN_S) / STEP_S
            ),
        )  # fmt: skip

    def judge(
        self,
        step: int,
        before: VehicleState,
        state: VehicleState,
        poses: list[AgentPose],
        distance_m: float,
    ) -> bool:
        """The rules at the step driven from `before` to `state` (`step`, the agents at
        `poses`, `distance_m` from the route as `progress` last measured it): its infractions
        counted, and whether the episode ends there."""
        bicycle = self.bicycle
        ego_centre = bicycle.centre_xy_m(state)
        ego_lw = (bicycle.length_m, bicycle.width_m)
        moved = float(np.hypot(*(state.xy_m - before.xy_m)))
        self.driven_m += moved
        events = self.events
        obstacles = [_obstacle(pose, self.traffic) for pose in poses] + self.rules.static
        for partner in rules.colliding(
            ego_centre, state.yaw_rad, ego_lw, state.speed_mps, obstacles
        ):
            if partner.partner_id not in self.hit_partners:
                self.hit_partners.add(partner.partner_id)
                kind = rules.collision_kind(partner)
                klass = partner.agent_class.value if partner.agent_class else "static"
                events.append(Event(kind, step, partner.partner_id, klass))
        for line_id in self.rules.red_lights_crossed(
            self._front(before), self._front(state), state.yaw_rad,
            signals_at(self.scenario, step),
        ):  # fmt: skip
            if line_id not in self.red_lines:
                self.red_lines.add(line_id)
                events.append(Event(Infraction.RED_LIGHT, step, line_id))
        wheels = rules.wheel_points(state.xy_m, state.yaw_rad, bicycle.wheelbase_m, bicycle.width_m)
        lane = self.rules.lane_status(ego_centre, state.yaw_rad, wheels)
        if lane in ("off_road", "wrong_lane"):
            self.outside_m += moved
            self.off_road_m += moved if lane == "off_road" else 0.0
            self.outside_first = step if self.outside_first < 0 else self.outside_first
            if lane == "off_road" and self.off_road_first < 0:
                self.off_road_first = step
        return self._ended(step, state, distance_m)

    def _ended(self, step: int, state: VehicleState, distance_m: float) -> bool:
        """Whether the route ends at `step`: completed (late or not), deviated, blocked or
        timed out, its event counted."""
        events = self.events
        if self.progress.completion_percent >= 100.0:
            if step > self.late_step:
                detail = f"{step * STEP_S:.1f} s"
                events.append(Event(Infraction.SCENARIO_TIMEOUT, step, detail=detail))
            return True
        if distance_m > rules.ROUTE_DEVIATION_M:
            detail = f"{distance_m:.1f} m off"
            events.append(Event(Infraction.ROUTE_DEVIATION, step, detail=detail))
            return True
        self.stopped = self.stopped + 1 if state.speed_mps < rules.BLOCKED_SPEED_MPS else 0
        if self.stopped > self.blocked_steps:
            detail = f"stopped {self.stopped * STEP_S:.1f} s"
            events.append(Event(Infraction.AGENT_BLOCKED, step, detail=detail))
            return True
        if step >= self.max_steps:
            events.append(Event(Infraction.ROUTE_TIMEOUT, step, detail=f"{step * STEP_S:.1f} s"))
            return True
        return False

    def _front(self, state: VehicleState) -> NDArray[np.float64]:
        """(2,) the middle of the ego's front bumper in the world."""
        bicycle = self.bicycle
        reach = bicycle.rear_axle_to_centre_m + 0.5 * bicycle.length_m
        return state.xy_m + reach * np.array([np.cos(state.yaw_rad), np.sin(state.yaw_rad)])


def _obstacle(pose: AgentPose, traffic: Traffic) -> Obstacle:
    return Obstacle(
        pose.track_id,
        traffic.classes[pose.track_id],
        np.array([pose.x_m, pose.y_m]),
        pose.yaw_rad,
        pose.length_m,
        pose.width_m,
    )
