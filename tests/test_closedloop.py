"""Closed loop with known answers: the bicycle and its controller, each infraction on a
hand-built straight road (collision 0.60 with the partner's id, red light 0.70, blocked,
off-road), the log-replay expert on the synthetic set, reactive traffic, occlusion variants."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from drivee2e_data import store
from drivee2e_data.agents.expert import LogReplayExpert
from drivee2e_data.curation.occlusion import Variant, unseen_agents
from drivee2e_data.evaluate.agent import AgentFailure, Waypoints, parse_action
from drivee2e_data.evaluate.episode import Episode, EpisodeOptions, make_route
from drivee2e_data.evaluate.traffic import Traffic
from drivee2e_data.hdmap import Area, StopLine
from drivee2e_data.metrics import closedloop
from drivee2e_data.metrics.closedloop import Event, Infraction
from drivee2e_data.scenario import AgentClass, SignalState, SignalTimeline
from drivee2e_data.sensors.ego_state import ego_motion, to_ego_frame
from drivee2e_data.sim.vehicle import Bicycle, Control, VehicleState, WaypointController
from tests.factories import small_map, small_scenario, straight_track

FRAMES = 50  # the ego drives 49 m east at 10 m/s


class Stop:
    name, sensors, image_size = "stop", (), None

    def setup(self, route, rig) -> None:
        pass

    def act(self, observation) -> Control:
        return Control(brake=1.0)


class VeerLeft:
    """Plans 45 degrees to the left of its heading at its speed."""

    name, sensors, image_size = "veer", (), None

    def setup(self, route, rig) -> None:
        pass

    def act(self, observation) -> Waypoints:
        steps = 5.0 * np.arange(1, 7)
        return Waypoints(np.column_stack([steps, steps]) / np.sqrt(2))


def road_map(**overrides):
    """The straight lane l1 (signal s1) with a drivable area 3.5 m wide around it."""
    area = Area("road", np.array([[-10.0, -1.75], [60.0, -1.75], [60.0, 1.75], [-10.0, 1.75]]))
    return small_map(drivable_areas=(area,), **overrides)


def road_scenario(*others, signal=SignalState.GREEN):
    ego = straight_track("ego", FRAMES)
    return small_scenario(
        FRAMES,
        tracks=(ego, *others),
        ego_id="ego",
        signals=(SignalTimeline("s1", np.full(FRAMES, signal.value, np.uint8)),),
    )


def parked(track_id: str, x_m: float, agent_class=AgentClass.CAR):
    return straight_track(
        track_id,
        FRAMES,
        agent_class,
        x_m=np.full(FRAMES, x_m),
        vx_mps=np.zeros(FRAMES),
    )


def run(scenario, agent=None, intersection_map=None, **options):
    episode = Episode(
        scenario,
        intersection_map or road_map(),
        agent or LogReplayExpert(),
        EpisodeOptions(**options),
    )
    return episode.run()


def test_bicycle_brakes_and_turns_as_its_equations_say() -> None:
    bicycle = Bicycle(length_m=5.0, width_m=2.0, rear_axle_to_centre_m=1.5)
    state = VehicleState(0.0, 0.0, 0.0, 8.0)
    for _ in range(10):
        state = bicycle.step(state, Control(brake=1.0))
    assert state.speed_mps == 0.0 and state.x_m == pytest.approx(3.6, abs=0.5)
    # steady turn: yaw rate = v tan(steer) / wheelbase once the wheels reached their angle
    state = VehicleState(0.0, 0.0, 0.0, 5.0, steer_rad=0.3)
    state = bicycle.step(state, Control(steer=0.5, throttle=0.0375))
    assert state.yaw_rate_radps == pytest.approx(state.speed_mps * np.tan(0.3) / 3.0, rel=1e-6)


def test_controller_follows_a_straight_plan_at_its_speed() -> None:
    """A lane along y = 0 planned at 10 m/s: from 0.5 m beside it at 5 m/s, the car is on it
    and at speed within 8 s."""
    bicycle, controller = Bicycle(4.6, 1.85, 1.38), WaypointController()
    state = VehicleState(0.0, 0.5, 0.0, 5.0)
    for _ in range(80):
        lane_ahead = np.column_stack([state.x_m + 5.0 * np.arange(1, 7), np.zeros(6)])
        plan = to_ego_frame(lane_ahead, state.x_m, state.y_m, state.yaw_rad)
        state = bicycle.step(state, controller.control(plan, state))
    assert state.speed_mps == pytest.approx(10.0, abs=0.2)
    assert abs(state.y_m) < 0.02 and abs(state.yaw_rad) < 0.01


def test_parse_action_rejects_garbage() -> None:
    assert isinstance(parse_action(Waypoints(np.zeros((6, 2)))), Waypoints)
    for bad in (None, "left", Waypoints(np.full((6, 2), np.nan)), Waypoints(np.zeros(3))):
        with pytest.raises(AgentFailure):
            parse_action(bad)


def test_expert_on_a_clean_road_scores_100() -> None:
    result = run(road_scenario())
    assert result.score.route_completion == 100.0
    assert result.score.driving_score == 100.0 and result.score.success


def test_driving_into_a_parked_car_is_a_vehicle_collision_with_its_id() -> None:
    result = run(road_scenario(parked("parked", 30.0)))
    collisions = [e for e in result.score.events if e.infraction is Infraction.COLLISION_VEHICLE]
    assert [(e.partner_id, e.detail) for e in collisions] == [("parked", "car")]
    assert result.score.penalty == pytest.approx(0.60)
    assert result.score.driving_score == pytest.approx(60.0) and not result.score.success


def test_a_pedestrian_collision_costs_half() -> None:
    result = run(road_scenario(parked("walker", 30.0, AgentClass.PEDESTRIAN)))
    assert result.score.count(Infraction.COLLISION_PEDESTRIAN) == 1
    assert result.score.penalty == pytest.approx(0.50)


def test_a_car_running_into_the_stopped_ego_is_not_the_egos_fault() -> None:
    follower = straight_track("follower", FRAMES, x_m=-20.0 + 10.0 * np.arange(FRAMES) * 0.1)
    result = run(road_scenario(follower), agent=Stop())
    assert not any(e.infraction in closedloop.COLLISIONS for e in result.score.events)


def test_running_a_red_light_costs_070() -> None:
    stop_line = StopLine("stop", np.array([[20.0, -1.75, 0.0], [20.0, 1.75, 0.0]]), ("l1",))
    intersection_map = road_map(stop_lines=(stop_line,))
    red = run(road_scenario(signal=SignalState.RED), intersection_map=intersection_map)
    assert [(e.infraction, e.partner_id) for e in red.score.events] == [
        (Infraction.RED_LIGHT, "stop")
    ]
    assert red.score.driving_score == pytest.approx(70.0)
    green = run(road_scenario(signal=SignalState.GREEN), intersection_map=intersection_map)
    assert green.score.events == ()


def test_stopping_forever_is_agent_blocked_with_the_route_completed_so_far() -> None:
    result = run(road_scenario(), agent=Stop())
    assert result.score.status == "agent_blocked"
    # it brakes from 10 m/s: about 6 m of the 49 m route before standing still
    assert 5.0 < result.score.route_completion < 20.0
    assert result.score.driving_score == pytest.approx(result.score.route_completion)
    blocked_after = closedloop.BLOCKED_MARGIN_S  # the logged ego never stopped
    assert result.sim_seconds == pytest.approx(blocked_after + 1.4, abs=0.6)


def test_leaving_the_road_is_an_off_road_share_and_then_a_deviation() -> None:
    result = run(road_scenario(), agent=VeerLeft())
    assert result.off_road_percent > 0.0
    assert result.score.outside_lanes_percent >= result.off_road_percent
    assert result.score.status == "route_deviation"
    assert result.score.penalty == pytest.approx(1 - result.score.outside_lanes_percent / 100)


def test_scores_multiply_and_success_needs_a_clean_complete_route() -> None:
    events = [Event(Infraction.COLLISION_VEHICLE, 3), Event(Infraction.RED_LIGHT, 9)]
    score = closedloop.score(100.0, events, outside_lanes_percent=10.0)
    assert score.driving_score == pytest.approx(100 * 0.6 * 0.7 * 0.9)
    assert not score.success
    assert closedloop.score(100.0, [], 0.0).success
    assert not closedloop.score(99.0, [], 0.0).success
    slow = closedloop.score(100.0, [], 0.0, min_speed_ratio=0.5)
    assert slow.penalty == pytest.approx(0.85) and slow.success  # min speed never fails a route


def test_route_progress_does_not_jump_to_the_way_back_of_a_u_turn() -> None:
    there = np.column_stack([np.linspace(0, 30, 61), np.zeros(61)])
    back = np.column_stack([np.linspace(30, 0, 61), np.full(61, 4.0)])
    progress = closedloop.RouteProgress(np.vstack([there, back]))
    reached, _ = progress.update(np.array([1.0, 3.5]))  # near the route's end, at its start
    assert reached < 5.0


@pytest.mark.slow
def test_expert_scores_the_log_on_the_synthetic_set(synthetic_scenarios, synthetic_root) -> None:
    maps = {}
    for scenario in synthetic_scenarios:
        if scenario.map_id not in maps:
            maps[scenario.map_id] = store.read_map(synthetic_root, scenario.map_id)
        result = run(scenario, intersection_map=maps[scenario.map_id])
        assert result.score.success, (scenario.scenario_id, result.score)
        assert result.score.driving_score >= 95.0


def test_route_waypoints_carry_the_logged_commands(synthetic_scenarios, synthetic_root) -> None:
    scenario = next(s for s in synthetic_scenarios if s.behavior.category.value == "LFT")
    motion = ego_motion(scenario)
    route = make_route(scenario, motion, store.read_map(synthetic_root, scenario.map_id))
    assert set(route.commands.tolist()) >= {2, 3}  # a left turn is announced, then straight
    assert np.allclose(route.waypoints_xy_m[0], [motion.x_m[0], motion.y_m[0]])
    assert route.waypoints_lat_lon_alt.shape == (len(route.waypoints_xy_m), 3)


def test_reactive_traffic_brakes_for_a_stopped_ego() -> None:
    follower = straight_track("follower", FRAMES, x_m=-20.0 + 10.0 * np.arange(FRAMES) * 0.1)
    scenario = road_scenario(follower)
    replay, reactive = Traffic(scenario), Traffic(scenario, reactive=True)
    ego_centre = np.array([1.4, 0.0])
    gaps = {}
    for name, traffic in (("replay", replay), ("reactive", reactive)):
        for step in range(FRAMES):
            poses = traffic.poses(step, ego_centre, 0.0, 0.0, (4.6, 1.85))
        (pose,) = poses
        gaps[name] = ego_centre[0] - pose.x_m - 0.5 * (4.6 + pose.length_m)
    assert gaps["replay"] < -20.0  # the log drives through the ego
    assert 0.5 < gaps["reactive"] < 6.0  # IDM stops behind it, about its minimum gap


def test_reactive_traffic_follows_its_log_when_nothing_is_in_the_way() -> None:
    follower = straight_track("follower", FRAMES, x_m=-20.0 + 10.0 * np.arange(FRAMES) * 0.1)
    traffic = Traffic(road_scenario(follower), reactive=True)
    far_away = np.array([500.0, 500.0])
    for step in range(FRAMES):
        (pose,) = traffic.poses(step, far_away, 0.0, 0.0, (4.6, 1.85))
        assert pose.x_m == pytest.approx(follower.x_m[step], abs=1e-6)


def test_occlusion_variants_drop_unseen_agents_by_class() -> None:
    seen_car, hidden_car = straight_track("seen", FRAMES), parked("hidden", 30.0)
    walker = parked("walker", 10.0, AgentClass.PEDESTRIAN)
    late = dataclasses.replace(
        parked("late", 40.0), valid=np.arange(FRAMES) >= 40
    )  # only after the collected frames
    scenario = road_scenario(seen_car, hidden_car, walker, late)
    collected = range(0, 30)
    assert unseen_agents(scenario, {"seen"}, collected, Variant.COMPLETE) == []
    assert unseen_agents(scenario, {"seen"}, collected, Variant.OCC_VEHICLE) == ["hidden"]
    assert unseen_agents(scenario, {"seen"}, collected, Variant.OCC_ALL) == ["hidden", "walker"]
    result = run(road_scenario(parked("hidden", 30.0)), removed_track_ids=frozenset({"hidden"}))
    assert result.score.success  # the parked car the cameras never saw is gone


class Later:
    """`agent` answered the way a policy server's agent is (`act_later`: the observation taken
    at once, the action read later), counting its requests."""

    def __init__(self, agent, fail_at: int = -1) -> None:
        self.agent, self.fail_at, self.requests = agent, fail_at, 0
        self.name, self.sensors, self.image_size = agent.name, agent.sensors, agent.image_size
        self.input_size = getattr(agent, "input_size", None)

    def setup(self, route, rig) -> None:
        self.agent.setup(route, rig)

    def act(self, observation):
        raise AssertionError("an agent with act_later is not asked to act")

    def act_later(self, observation):
        self.requests += 1
        if observation.step == self.fail_at:
            raise AgentFailure("the server is gone")
        action = self.agent.act(observation)
        return lambda: action


def same_episode(one, other) -> None:
    """Two episodes' results equal in all but their timings, step by step where traced."""
    timing = {"wall_seconds", "observe_seconds", "agent_seconds", "trace"}
    for name in {f.name for f in dataclasses.fields(one)} - timing:
        assert getattr(one, name) == getattr(other, name), name
    assert [dataclasses.astuple(r.state) for r in one.trace] == [
        dataclasses.astuple(r.state) for r in other.trace
    ]
    assert [r.agents for r in one.trace] == [r.agents for r in other.trace]


@pytest.mark.parametrize(
    ("scenario", "agent", "status"),
    [
        (road_scenario, LogReplayExpert, "completed"),
        (lambda: road_scenario(parked("parked", 30.0)), LogReplayExpert, "completed"),
        (lambda: road_scenario(signal=SignalState.RED), LogReplayExpert, "completed"),
        (road_scenario, Stop, "agent_blocked"),
        (road_scenario, VeerLeft, "route_deviation"),
    ],
)
def test_an_agent_answered_later_drives_the_same_episode(scenario, agent, status) -> None:
    """With `act_later` the rules judge each step while the agent thinks: the same events,
    steps and scores as acting at once, whichever way the episode ends; one request more, the
    observation of the step the rules ended the episode at, whose answer is read and dropped."""
    stop_line = StopLine("stop", np.array([[20.0, -1.75, 0.0], [20.0, 1.75, 0.0]]), ("l1",))
    intersection_map = road_map(stop_lines=(stop_line,))
    at_once = Episode(scenario(), intersection_map, agent(), keep_trace=True).run()
    later = Later(agent())
    result = Episode(scenario(), intersection_map, later, keep_trace=True).run()
    assert result.score.status == status
    same_episode(result, at_once)
    assert later.requests == result.steps + 1


def test_a_request_that_fails_ends_the_episode_where_acting_at_once_fails() -> None:
    class FailsAt(VeerLeft):
        def act(self, observation):
            if observation.step == 7:
                raise AgentFailure("the server is gone")
            return super().act(observation)

    at_once = run(road_scenario(), agent=FailsAt())
    result = run(road_scenario(), agent=Later(VeerLeft(), fail_at=7))
    assert result.score.status == "agent_failed" and result.steps == 7
    assert result.score.events == at_once.score.events and result.failure == at_once.failure


class PixelSteer:
    """A camera agent whose plan follows its front camera's pixels (it steers toward the
    brighter half), keeping a digest of every image it was given."""

    name, sensors, image_size, input_size = "pixels", ("CAM_FRONT",), (320, 180), (80, 45)

    def __init__(self) -> None:
        self.seen: list[int] = []

    def setup(self, route, rig) -> None:
        pass

    def act(self, observation) -> Waypoints:
        image = observation.pixels["CAM_FRONT"]
        self.seen.append(hash(image.tobytes()))
        half = image.shape[2] // 2
        lateral = 0.01 * (float(image[:, :, :half].mean()) - float(image[:, :, half:].mean()))
        ahead = max(observation.speed_mps, 3.0) * 0.5 * np.arange(1, 7)
        return Waypoints(np.column_stack([ahead, lateral * np.arange(1, 7)]))


@pytest.mark.parametrize("pose_on_gpu", [False, True])
def test_a_scene_shown_while_the_agent_thinks_gives_the_same_pixels(
    synthetic_root, pose_on_gpu
) -> None:
    """A camera agent answered later on log-replay traffic: the next step's agents, signals
    and models are shown and handed to the renderer while it thinks, the ego placed after (its
    headlights and shadow made again): every image and the episode as when acting at once, at
    night in fog (c0011, headlights) with the models posed on the CPU and as a GPU poses them."""
    from drivee2e_data.sim.world import World

    scenario = store.read_scenario(synthetic_root, "synth_s0_c0011")
    intersection_map = store.read_map(synthetic_root, scenario.map_id)
    results, seen = [], []
    with World(intersection_map, scenario, "auto") as world:
        if world.renderer != "gl":
            pytest.skip("the closed-loop cameras draw with the GL renderer (no EGL here)")
        if pose_on_gpu:
            world.gl.cull = world.gl.one_program = world.gl.poses_on_gpu = True
            world.gl.forget_bodies()
            world.gl.set_models(world.body_models())
        for agent in (PixelSteer(), Later(PixelSteer())):
            world.replay(scenario)
            episode = Episode(scenario, intersection_map, agent, world=world, keep_trace=True)
            results.append(episode.run())
            seen.append(getattr(agent, "agent", agent).seen)
    assert results[0].steps > 50 and results[0].failure == ""
    same_episode(results[1], results[0])
    assert seen[1][: len(seen[0])] == seen[0] and len(seen[1]) == len(seen[0]) + 1
