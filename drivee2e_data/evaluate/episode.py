"""One closed-loop episode at 10 Hz: the ego starts at its first logged pose and speed, the
agent observes and acts, the kinematic bicycle moves, every other agent and signal follows its
log (or IDM along its path with `reactive`), and the route's rules are checked at every step.

Step k: the agent observes the scene at k from the ego's state at k; its action moves the ego
to k+1; the checks compare the ego at k+1 with the scene at k+1. The episode ends when the
route is complete or an infraction ends it (deviation, blocked, timeout, agent failure); the
rules at each step are `evaluate/judge.py`'s.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.evaluate.agent import (
    Agent,
    AgentFailure,
    Observation,
    Route,
    Waypoints,
    parse_action,
)
from drivee2e_data.evaluate.judge import StepJudge, signals_at
from drivee2e_data.evaluate.traffic import AgentPose, Traffic
from drivee2e_data.geometry import next_waypoint, polyline_arclength
from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.metrics import closedloop as rules
from drivee2e_data.metrics.closedloop import Event, Infraction, MapRules, RouteProgress
from drivee2e_data.scenario import Scenario
from drivee2e_data.sensors.ego_state import EgoMotion, ego_motion, to_ego_frame
from drivee2e_data.sensors.imu_gnss import enu_to_wgs84
from drivee2e_data.sim.vehicle import Bicycle, Control, VehicleState, WaypointController

STEP_S = 0.1
ROUTE_WAYPOINT_SPACING_M = 5.0
TARGET_POINT_MIN_M = 10.0  # as the Dataset's target_point
HISTORY_STEPS = 4  # 2 Hz history over 2 s, as the Dataset's default
HISTORY_STRIDE = 5


@dataclass(frozen=True)
class EpisodeOptions:
    reactive: bool = False
    min_speed: bool = False  # LB2's minimum-speed penalty (off, as Bench2Drive)
    removed_track_ids: frozenset[str] = frozenset()  # occlusion variants drop these agents
    # JPEGs at the collection size for every camera agent, even one that declares the size it
    # reads (`Agent.input_size`): the collection's own path, to check the cheap one against
    exact_images: bool = False


@dataclass
class StepRecord:
    """What happened at one step, for recording and debugging."""

    step: int
    state: VehicleState
    control: Control
    agents: list[AgentPose]
    planned_xy_m: NDArray[np.float64] | None


@dataclass
class EpisodeResult:
    scenario_id: str
    score: rules.EpisodeScore
    steps: int
    driven_m: float
    route_length_m: float
    off_road_percent: float
    sim_seconds: float
    wall_seconds: float
    failure: str = ""
    # where the wall time went: drawing and preparing the agent's inputs, and the agent's act
    # (its network, or the wait on its policy server); the rest is the simulation and the rules
    observe_seconds: float = 0.0
    agent_seconds: float = 0.0
    trace: list[StepRecord] = field(default_factory=list)
    # the first step driven outside the route's lanes, and off the road (-1: never)
    outside_first_step: int = -1
    off_road_first_step: int = -1


def logged_route(motion: EgoMotion) -> NDArray[np.float64]:
    """(T, 2) the logged rear-axle path: the route the ego must drive."""
    return np.stack([motion.x_m, motion.y_m], -1)


def make_route(scenario: Scenario, motion: EgoMotion, intersection_map: IntersectionMap) -> Route:
    """The route an agent is given: logged path waypoints every 5 m, with the logged command at
    the frame the driver passed each."""
    xy = logged_route(motion)
    s_frames = polyline_arclength(xy)
    samples = np.append(np.arange(0.0, s_frames[-1], ROUTE_WAYPOINT_SPACING_M), s_frames[-1])
    frames = np.minimum(np.searchsorted(s_frames, samples, side="left"), len(xy) - 1)
    waypoints = xy[frames]
    ground = np.column_stack([waypoints, motion.z_m[frames]])
    behavior = scenario.behavior
    return Route(
        scenario_id=scenario.scenario_id,
        waypoints_xy_m=waypoints,
        commands=motion.command[frames].astype(np.int64),
        waypoints_lat_lon_alt=enu_to_wgs84(ground, intersection_map.origin),
        logged_path_txy=np.column_stack([(motion.t_ns - motion.t_ns[0]) * 1e-9, xy]),
        category=behavior.category.value if behavior is not None else "",
    )


class Episode:
    """Runs `agent` on one scenario. `world` (a `sim.world.World` showing the scenario) is
    needed only when the agent asks for sensors."""

    def __init__(
        self,
        scenario: Scenario,
        intersection_map: IntersectionMap,
        agent: Agent,
        options: EpisodeOptions = EpisodeOptions(),
        world: Any = None,
        map_rules: MapRules | None = None,
        keep_trace: bool = False,
    ) -> None:
        self.scenario, self.map, self.agent, self.options = (
            scenario,
            intersection_map,
            agent,
            options,
        )
        self.keep_trace = keep_trace
        route_lanes = scenario.route.lane_ids if scenario.route is not None else ()
        self.rules = map_rules or MapRules(intersection_map, route_lanes)
        self.motion = ego_motion(scenario)
        self.route = make_route(scenario, self.motion, intersection_map)
        size = self.motion.size_m
        self.bicycle = Bicycle(float(size[0]), float(size[1]), self.motion.rear_axle_to_centre_m)
        self.traffic = Traffic(scenario, options.reactive, options.removed_track_ids)
        self.route_xy = logged_route(self.motion)
        self.s_frames = polyline_arclength(self.route_xy)
        self.route_waypoints = (
            scenario.route.waypoints_xy_m
            if scenario.route is not None
            else self.route.waypoints_xy_m
        )
        self.observer = None
        if tuple(agent.sensors):
            from drivee2e_data.evaluate.observation import SensorObserver

            if world is None:
                raise ValueError(
                    f"agent {agent.name!r} asks for sensors: the episode needs a world"
                )
            input_size = None if options.exact_images else getattr(agent, "input_size", None)
            self.observer = SensorObserver(
                world, tuple(agent.sensors), agent.image_size, input_size
            )

    def run(self) -> EpisodeResult:
        start = time.perf_counter()
        scenario, motion = self.scenario, self.motion
        state = VehicleState(
            float(motion.x_m[0]), float(motion.y_m[0]), float(motion.yaw_rad[0]),
            float(motion.speed_mps[0]), steer_rad=float(motion.steer_rad[0]),
        )  # fmt: skip
        rig = self.observer.rig if self.observer is not None else None
        failure = ""
        try:
            self.agent.setup(self.route, rig)
        except AgentFailure as error:
            failure = str(error)
        except Exception as error:  # the agent's own code: its bug ends its episode only
            failure = f"setup raised {type(error).__name__}: {error}"
        progress = RouteProgress(self.route_xy)
        controller = WaypointController(self.bicycle.wheelbase_m)
        judge = StepJudge.for_episode(scenario, self.rules, self.traffic, self.bicycle, progress,
                                      motion.speed_mps)  # fmt: skip
        events = judge.events
        history: list[VehicleState] = [state]
        poses = self.traffic.poses(
            0, self.bicycle.centre_xy_m(state), state.yaw_rad, state.speed_mps, self._ego_lw()
        )
        trace: list[StepRecord] = []
        step = 0
        observe_s = agent_s = 0.0
        # an agent answered by another process (`act_later`: a policy server's) is waited for
        # while this one judges the step just driven and, where the traffic does not follow
        # the ego, shows the next step's scene: the same episode, this process's work done
        # beside the network's rather than after it
        later = getattr(self.agent, "act_later", None)
        ahead = later is not None and self.observer is not None and self.traffic.ego_blind
        driven: tuple[Any, ...] | None = None  # the step driven, judged while the agent thinks
        shown: list[AgentPose] | None = None  # the next step's agents, shown ahead
        while not failure:
            began = time.perf_counter()
            observation = self._observe(
                step, state, history, poses, progress.progress_m, shown is not None
            )
            observed = time.perf_counter()
            observe_s += observed - began
            try:
                if later is None:
                    action = parse_action(self.agent.act(observation))
                else:
                    answer = _submitted(later, observation)
                    agent_s += time.perf_counter() - observed
                    ended = driven is not None and judge.judge(*driven)
                    shown = self._show_ahead(step + 1) if ahead and not ended else None
                    observed = time.perf_counter()
                    if ended:  # the step driven ended the episode: this answer is not needed
                        _drain(answer)
                        break
                    action = parse_action(answer())
            except AgentFailure as error:
                failure = str(error)
                break
            except Exception as error:
                failure = f"act raised {type(error).__name__}: {error}"
                break
            finally:
                agent_s += time.perf_counter() - observed
            planned = None
            if isinstance(action, Waypoints):
                planned = action.xy_m
                control = controller.control(action.xy_m, state)
            else:
                control = action
            before = state
            state = self.bicycle.step(state, control)
            history.append(state)
            step += 1
            ego_centre = self.bicycle.centre_xy_m(state)
            if shown is None:
                poses = self.traffic.poses(
                    step, ego_centre, state.yaw_rad, state.speed_mps, self._ego_lw()
                )
            else:  # shown ahead: the traffic's poses did not depend on where the ego went
                poses = shown
            if self.keep_trace:
                trace.append(StepRecord(step - 1, before, control, poses, planned))
            # before the next observation, which reads the progress
            _reached, distance = progress.update(state.xy_m)
            driven = (step, before, state, poses, distance)
            if later is None and judge.judge(*driven):
                break
        if failure:
            events.append(Event(Infraction.AGENT_FAILED, step, detail=failure))
        length = progress.length_m
        ratio = None
        if self.options.min_speed and step > 0:
            logged_speed = length / max(scenario.duration_s, STEP_S)
            ratio = (progress.progress_m / (step * STEP_S)) / max(logged_speed, 1e-6)
            if ratio < 1.0:
                events.append(
                    Event(Infraction.MIN_SPEED, step, detail=f"{100 * ratio:.0f}% of the log")
                )
        outside_percent = 100.0 * judge.outside_m / max(length, 1e-6)
        score = rules.score(progress.completion_percent, events, outside_percent, ratio)
        return EpisodeResult(
            scenario_id=scenario.scenario_id,
            score=score,
            steps=step,
            driven_m=judge.driven_m,
            route_length_m=length,
            off_road_percent=min(100.0, 100.0 * judge.off_road_m / max(length, 1e-6)),
            sim_seconds=step * STEP_S,
            wall_seconds=time.perf_counter() - start,
            failure=failure,
            trace=trace,
            outside_first_step=judge.outside_first,
            off_road_first_step=judge.off_road_first,
            observe_seconds=observe_s,
            agent_seconds=agent_s,
        )

    def _show_ahead(self, step: int) -> list[AgentPose]:
        """The agents at `step`, shown in the world with the signals (`SensorObserver.show`)
        before the ego drives there: where the traffic does not follow the ego, what the next
        observation would show first."""
        poses = self.traffic.poses(step)
        assert self.observer is not None
        self.observer.show(
            min(step, self.scenario.num_frames - 1), poses, signals_at(self.scenario, step)
        )
        return poses

    def _ego_lw(self) -> tuple[float, float]:
        return self.bicycle.length_m, self.bicycle.width_m

    def _observe(
        self,
        step: int,
        state: VehicleState,
        history: list[VehicleState],
        poses: list[AgentPose],
        progress_m: float,
        shown: bool = False,
    ) -> Observation:
        frame = int(np.searchsorted(self.s_frames, progress_m + 1e-6, side="right")) - 1
        frame = min(max(frame, 0), self.scenario.num_frames - 1)
        z = float(self.motion.z_m[frame])
        rows = [step - HISTORY_STRIDE * k for k in range(HISTORY_STEPS, 0, -1)]
        mask = np.array([r >= 0 for r in rows])
        past = np.array([history[max(r, 0)].xy_m for r in rows])
        history_xy = to_ego_frame(past, state.x_m, state.y_m, state.yaw_rad)
        history_xy[~mask] = 0.0
        lateral = state.speed_mps * state.yaw_rate_radps
        acceleration = np.array([state.acceleration_mps2, lateral, 9.81])
        angular = np.array([0.0, 0.0, state.yaw_rate_radps])
        status = np.concatenate(
            [acceleration, angular, [state.speed_mps, 0.0, 0.0], [state.steer_rad]]
        )
        target = next_waypoint(self.route_waypoints, state.xy_m, TARGET_POINT_MIN_M)
        images: dict[str, Any] = {}
        pixels: dict[str, Any] = {}
        lidar_points = None
        if self.observer is not None:
            images, lidar_points = self.observer.observe(
                step, min(step, self.scenario.num_frames - 1), state, z, poses,
                signals_at(self.scenario, step), self.bicycle.centre_xy_m(state), shown=shown,
            )  # fmt: skip
            if self.observer.input_size is not None:
                images, pixels = {}, images
        return Observation(
            step=step,
            t_s=step * STEP_S,
            xy_m=state.xy_m,
            yaw_rad=state.yaw_rad,
            lat_lon_alt=enu_to_wgs84(np.array([[state.x_m, state.y_m, z]]), self.map.origin)[0],
            speed_mps=state.speed_mps,
            imu_acceleration_mps2=acceleration,
            imu_angular_velocity_radps=angular,
            ego_status=status,
            history_xy_m=history_xy,
            history_mask=mask,
            command=int(self.motion.command[frame]),
            target_point_m=to_ego_frame(target[None], state.x_m, state.y_m, state.yaw_rad)[0],
            images=images,
            lidar_points=lidar_points,
            pixels=pixels,
        )


def _submitted(later: Any, observation: Observation) -> Any:
    """`later(observation)`'s waiting function, or one that raises what `later` raised: a
    failed request fails its step as a failed answer does, after the step before is judged."""
    try:
        return later(observation)
    except Exception as error:  # raised again where the answer is read
        failed = error

        def fail() -> Any:
            raise failed

        return fail


def _drain(answer: Any) -> None:
    """Read an answer that is not needed (a served agent takes one request at a time); what
    it raises no longer matters."""
    try:
        answer()
    except Exception:  # the episode has ended: its result is set
        pass
