"""Small hand-built scenarios and maps for tests, and helpers shared by the render tests."""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from drivee2e_data.hdmap import GeoOrigin, IntersectionMap, Lane, SignalHead
from drivee2e_data.scenario import (
    FRAME_PERIOD_NS,
    AgentClass,
    Conditions,
    Scenario,
    SignalState,
    SignalTimeline,
    TimeOfDay,
    Track,
    Weather,
)

T0_NS = 1_780_000_000_000_000_000


def straight_track(
    track_id: str = "a", frames: int = 5, agent_class: AgentClass = AgentClass.CAR, **overrides
) -> Track:
    """A car driving east at 10 m/s from the origin."""
    t = np.arange(frames) * 0.1
    fields = dict(
        x_m=10.0 * t,
        y_m=np.zeros(frames),
        z_m=np.full(frames, 0.75),
        yaw_rad=np.zeros(frames),
        length_m=np.full(frames, 4.5),
        width_m=np.full(frames, 1.8),
        height_m=np.full(frames, 1.5),
        vx_mps=np.full(frames, 10.0),
        vy_mps=np.zeros(frames),
        valid=np.ones(frames, bool),
    )
    fields.update(overrides)
    return Track(track_id=track_id, agent_class=agent_class, **fields)


def small_scenario(frames: int = 5, **overrides) -> Scenario:
    fields = dict(
        scenario_id="tiny",
        map_id="tiny_map",
        source="test",
        t_ns=T0_NS + FRAME_PERIOD_NS * np.arange(frames, dtype=np.int64),
        tracks=(straight_track("a", frames), straight_track("b", frames, AgentClass.PEDESTRIAN)),
        signals=(SignalTimeline("s1", np.full(frames, SignalState.GREEN.value, np.uint8)),),
        conditions=Conditions(
            Weather.RAIN, TimeOfDay.NIGHT, datetime(2026, 5, 1, 13, tzinfo=timezone.utc)
        ),
        ego_id="a",
    )
    fields.update(overrides)
    return Scenario(**fields)


def small_map(**overrides) -> IntersectionMap:
    centre = np.array([[0.0, 0.0, 0.0], [50.0, 0.0, 0.0]])
    half_width = np.array([0.0, 1.75, 0.0])
    lane = Lane("l1", centre, centre + half_width, centre - half_width, signal_id="s1")
    fields = dict(
        map_id="tiny_map",
        origin=GeoOrigin(39.9, 116.4, 40.0),
        lanes=(lane,),
        signal_heads=(
            SignalHead("h1", "s1", np.array([55.0, 2.0, 5.0]), np.pi, controlled_lane_ids=("l1",)),
        ),
    )
    fields.update(overrides)
    return IntersectionMap(**fields)


def assert_sun_matches_label(conditions: Conditions, origin: GeoOrigin) -> None:
    """The sun the renderer places for a clip agrees with its time-of-day label: high for
    morning, noon and afternoon, low but up for early morning and dusk, street lights at night."""
    import math

    from drivee2e_data.sim.conditions import lighting
    from drivee2e_data.sun import sun_position

    elevation = math.degrees(sun_position(conditions.start_time_utc, origin)[1])
    label = conditions.time_of_day
    where = f"{label.value} at {conditions.start_time_utc.isoformat()} ({origin})"
    assert lighting(conditions, origin).night == (label == TimeOfDay.NIGHT), where
    if label in (TimeOfDay.MORNING, TimeOfDay.NOON, TimeOfDay.AFTERNOON):
        assert elevation >= 15.0, where
    elif label in (TimeOfDay.EARLY_MORNING, TimeOfDay.DUSK):
        assert -4.0 <= elevation < 15.0, where
    else:
        assert elevation < -4.0, where


# a model of each kind of joint: steering and turning wheels (car, bus), walking legs and arms
# (pedestrian), pedals and a rider (bicycle): what the posing tests pose
JOINTED_MODELS = [
    (AgentClass.CAR, "sedan", (4.6, 1.85, 1.45)), (AgentClass.BUS, "bus", (11.0, 2.5, 3.2)),
    (AgentClass.PEDESTRIAN, "pedestrian", (0.6, 0.6, 1.72)),
    (AgentClass.CYCLIST, "bicycle", (1.8, 0.6, 1.7)),
]  # fmt: skip


def synthetic_clip(root: Path) -> tuple[IntersectionMap, Scenario]:
    """The map and the one clip of a seed-3 synthetic set written under `root`."""
    from drivee2e_data import pipeline, store

    pipeline.synthesize(root, clips=1, seed=3)
    scenario = store.read_scenario(root, store.scenario_ids(root)[0])
    return store.read_map(root, scenario.map_id), scenario


def front_view(world, frame: int, size: tuple[int, int] = (160, 90), **options):
    """`world.render` from the ego's logged pose at `frame`, 1.6 m up, looking along its
    heading with a 40-degree vertical field of view (the ego hidden, the frame's scene set)."""
    ego = world.scenario.ego
    world.place_ego(float(ego.x_m[frame]), float(ego.y_m[frame]), ego.track_id)
    world.set_time(frame)
    eye = np.array([ego.x_m[frame], ego.y_m[frame], 1.6])
    yaw = ego.yaw_rad[frame]
    target = eye + 10 * np.array([np.cos(yaw), np.sin(yaw), 0.0])
    return world.render(eye, target, *size, 40.0, **options)


def pose_on_cpu(world) -> None:
    """A GL `world` whose renderer poses the actors' models on the CPU (`PlacedModel`), as where
    GL draws on the CPU, whatever its other choices."""
    world.gl.poses_on_gpu = False
    world.gl.set_models(world.body_models())
    if world.gl.posed is not None:
        world.gl.posed.release()
        world.gl.posed = None


def egl_world(intersection_map: IntersectionMap, scenario: Scenario):
    """A `World` drawn by pybullet's EGL plugin; the test is skipped where the plugin does not
    load."""
    import pytest

    from drivee2e_data.errors import DriveE2EError
    from drivee2e_data.sim.world import World

    try:
        return World(intersection_map, scenario, renderer="egl")
    except DriveE2EError:
        pytest.skip("pybullet's EGL plugin does not load here")
