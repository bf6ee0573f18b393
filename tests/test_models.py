"""Procedural models and their motion: boxes filled exactly, wheels that turn by distance,
steps by stride, brake lights by deceleration, shadows away from the sun, instance pixels
inside their boxes."""

from __future__ import annotations

import numpy as np
import pytest

from drivee2e_data.scenario import AgentClass
from drivee2e_data.sim.actors import BLUEPRINTS, convex_parts
from drivee2e_data.sim.animation import animation_at, track_motion
from drivee2e_data.sim.conditions import ShaderLook
from drivee2e_data.sim.gl_context import gl_available
from drivee2e_data.sim.gl_renderer import GLRenderer
from drivee2e_data.sim.gl_vertices import PlacedModel
from drivee2e_data.sim.models import Animation, Light, agent_model, palette, pose, vehicles
from drivee2e_data.sim.models.mesh import HIP_SWING_RAD, face_normals
from drivee2e_data.sim.twin_plan import TwinMesh, box_mesh
from tests.factories import JOINTED_MODELS, straight_track

MOTOR = (AgentClass.CAR, AgentClass.VAN, AgentClass.TRUCK, AgentClass.BUS)
RIDDEN = (AgentClass.CYCLIST, AgentClass.MOTORCYCLIST, AgentClass.TRICYCLIST)
needs_gl = pytest.mark.skipif(not gl_available(), reason="no OpenGL context (EGL) here")


def _blueprints(classes):
    return [(c, name, (length, width, height)) for c in classes
            for name, length, width, height in BLUEPRINTS[c]]  # fmt: skip


@pytest.mark.parametrize(("agent_class", "name", "size"), _blueprints(MOTOR))
def test_a_vehicle_fills_its_box_to_a_centimetre_on_each_axis(agent_class, name, size):
    model = agent_model(agent_class, name, size, "track-7")
    half = 0.5 * np.asarray(size)
    assert np.allclose(model.extent_max_m, half, atol=0.01), name
    assert np.allclose(model.extent_min_m, -half, atol=0.01), name
    assert model.wheel_radius_m > 0.2


@pytest.mark.parametrize(
    ("agent_class", "name", "size"), _blueprints((*RIDDEN, AgentClass.PEDESTRIAN))
)
def test_people_and_riders_stay_inside_their_boxes_however_they_move(agent_class, name, size):
    model = agent_model(agent_class, name, size, "person-3")
    half = 0.5 * np.asarray(size) + 1e-4
    for phase in np.linspace(0.0, 2 * np.pi, 13):
        positions, _, _ = pose(model, Animation(wheel_angle_rad=phase, walk_phase_rad=phase,
                                                walk_amount=1.0))  # fmt: skip
        assert np.all(np.abs(positions) <= half), (name, phase)
    # feet (or wheels) on the floor of the box
    assert model.extent_min_m[2] == pytest.approx(-half[2], abs=0.02)


def test_colours_are_drawn_per_instance_and_the_same_every_time():
    size = (4.6, 1.85, 1.45)
    first = agent_model.__wrapped__(AgentClass.CAR, "sedan", size, "car-1")
    again = agent_model.__wrapped__(AgentClass.CAR, "sedan", size, "car-1")
    assert np.array_equal(first.colours, again.colours)
    paints = {tuple(agent_model(AgentClass.CAR, "sedan", size, f"car-{k}").colours[0].round(2))
              for k in range(40)}  # fmt: skip
    assert len(paints) > 5  # many instances, several colours


def test_a_vehicle_is_its_blueprints_shared_shape_painted_as_if_built_with_its_colours():
    """`vehicle_model` paints a shape built once per blueprint: every array equals the model
    built directly with the instance's colours, and all but the colours are the shape's own."""
    for blueprint, size in (("sedan", (4.6, 1.85, 1.45)), ("box_truck", (7.5, 2.5, 3.4))):
        for instance in ("car-1", "car-2"):
            rng = palette.instance_rng(instance)
            paint = palette.car_colour(rng)
            if blueprint == "sedan":
                direct = vehicles.car_like(vehicles.SEDAN, np.asarray(size), paint)
            else:
                cargo = palette.pick(palette.CARGO_COLOURS, rng)
                direct = vehicles.truck(np.asarray(size), paint, cargo, tractor=False)
            model = vehicles.vehicle_model(blueprint, size, instance)
            for field in ("positions", "normals", "colours", "materials", "lights", "joints"):
                assert np.array_equal(getattr(model, field), getattr(direct, field)), field
            assert model.positions is vehicles.vehicle_shape(blueprint, size).positions
            assert (model.colours >= 0).all()  # no placeholder left
            assert np.isclose(model.colours, np.float32(paint)).all(axis=1).sum() > 100


def test_mesh_triangles_face_outwards_on_a_car_body():
    """The hull's normals point away from the car's centre line on its sides (mid-length, clear
    of the mirrors)."""
    model = agent_model(AgentClass.CAR, "sedan", (4.6, 1.85, 1.45), "c")
    triangles = model.positions.reshape(-1, 3, 3)
    centres = triangles.mean(axis=1)
    normals = face_normals(model.positions.astype(np.float64))
    sides = (
        (model.joints[::3] == 0) & (np.abs(centres[:, 1]) > 0.85) & (np.abs(centres[:, 0]) < 0.5)
    )
    assert sides.sum() >= 8
    assert np.all(np.sign(normals[sides, 1]) == np.sign(centres[sides, 1]))


def test_wheels_turn_by_distance_over_circumference():
    """A car 10 m/s east for 3 s: at each frame its wheels have turned distance / radius; a
    point on the rim is carried round by that angle about the axle."""
    track = straight_track("a", 31)
    motion = track_motion(track)
    model = agent_model(AgentClass.CAR, "sedan", (4.6, 1.85, 1.45), "a")
    animation = animation_at(motion, 30, model, headlights=False, walks=False)
    assert motion.distance_m[30] == pytest.approx(30.0)
    assert animation.wheel_angle_rad == pytest.approx(30.0 / model.wheel_radius_m)
    revolutions = 30.0 / (2 * np.pi * model.wheel_radius_m)
    assert animation.wheel_angle_rad / (2 * np.pi) == pytest.approx(revolutions)
    wheel = 1 + next(k for k, j in enumerate(model.joint_table[1:]) if j.kind == "wheel")
    vertices = model.joints == wheel
    pivot = np.asarray(model.joint_table[wheel].pivot_m)
    rest, _, _ = pose(model, Animation())
    turned, _, _ = pose(model, Animation(wheel_angle_rad=0.5))
    before, after = rest[vertices] - pivot, turned[vertices] - pivot
    angle_before = np.arctan2(before[:, 0], before[:, 2])
    angle_after = np.arctan2(after[:, 0], after[:, 2])
    far = np.hypot(before[:, 0], before[:, 2]) > 0.1
    step = np.angle(np.exp(1j * (angle_after - angle_before)))[far]
    assert np.allclose(step, 0.5, atol=1e-4)  # forward roll: the top moves ahead (+x)
    assert np.allclose(after[:, 1], before[:, 1], atol=1e-5)  # about the axle (y)


@pytest.mark.parametrize(
    ("agent_class", "name", "size"),
    JOINTED_MODELS,
)
def test_a_placed_model_is_its_posed_mesh_moved_to_the_body(agent_class, name, size):
    """The renderer's one-pass placing (`PlacedModel`) gives the triangles of `pose` rotated
    by the body's quaternion and moved to its position: the same triangles (in joint order),
    within float32 rounding, with their colours, body id, material and lights."""
    model = agent_model(agent_class, name, size, "placed")
    placer = PlacedModel(model, body=7)
    animation = Animation(wheel_angle_rad=2.1, steer_rad=0.15, walk_phase_rad=1.3,
                          walk_amount=0.8, brake=True, headlights=True)  # fmt: skip
    yaw, position = 0.7, np.array([12.0, -3.0, 0.4])
    quaternion = (0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2))
    rotation = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    positions, normals, emission = pose(model, animation)
    out = placer.vertices(animation, tuple(position), quaternion)
    order = placer.order
    assert sorted(order.tolist()) == list(range(len(model.positions)))
    assert np.allclose(out[:, 0:3], positions[order] @ rotation.T + position, atol=2e-5)
    assert np.allclose(out[:, 3:6], normals[order] @ rotation.T, atol=2e-6)
    assert np.array_equal(out[:, 6:9], model.colours[order])
    assert np.all(out[:, 9] == 8)
    assert np.array_equal(out[:, 10], emission[order])
    assert np.array_equal(out[:, 11], model.materials[order].astype(np.float32))
    # each triangle stays whole: its three vertices are consecutive and from one joint
    assert np.all(np.ptp(np.asarray(model.joints)[order].reshape(-1, 3), axis=1) == 0)


def test_brake_lights_follow_deceleration():
    """Braking from 10 m/s at 3 m/s^2 shows the brake lights; cruising does not; a parked car
    (never moved) does not either."""
    frames = 40
    speed = np.concatenate([np.full(10, 10.0), np.maximum(10.0 - 0.3 * np.arange(1, 31), 2.0)])
    x = np.concatenate([[0.0], np.cumsum(speed[1:] * 0.1)])
    braking = track_motion(straight_track("b", frames, x_m=x, vx_mps=speed))
    cruising = track_motion(straight_track("c", frames))
    parked = track_motion(
        straight_track("p", frames, x_m=np.zeros(frames), vx_mps=np.zeros(frames))
    )
    assert braking.braking[15:30].all() and not braking.braking[:5].any()
    assert not cruising.braking.any()
    assert not parked.braking.any()


def test_a_walking_figures_legs_differ_half_a_stride_apart_and_a_standing_ones_do_not():
    model = agent_model(AgentClass.PEDESTRIAN, "pedestrian", (0.6, 0.6, 1.72), "walker")
    legs = np.isin(
        model.joints, [k for k, j in enumerate(model.joint_table) if j.kind in ("hip", "knee")]
    )
    frames = 30
    walking = straight_track("w", frames, AgentClass.PEDESTRIAN, x_m=1.4 * np.arange(frames) * 0.1,
                             vx_mps=np.full(frames, 1.4))  # fmt: skip
    standing = straight_track("s", frames, AgentClass.PEDESTRIAN, x_m=np.zeros(frames),
                              vx_mps=np.zeros(frames))  # fmt: skip
    half_stride_frames = round(0.5 * model.stride_m / 0.14)  # 1.4 m/s: 0.14 m a frame
    # the frame whose legs are farthest apart (phase nearest a quarter cycle)
    phases = 2 * np.pi * track_motion(walking).distance_m / model.stride_m
    start = 5 + int(np.argmax(np.abs(np.sin(phases[5:12]))))
    for track, differ in ((walking, True), (standing, False)):
        motion = track_motion(track)
        first = animation_at(motion, start, model, False, walks=True)
        later = animation_at(motion, start + half_stride_frames, model, False, walks=True)
        a, _, _ = pose(model, first)
        b, _, _ = pose(model, later)
        moved = np.abs(a[legs] - b[legs]).max()
        if differ:
            assert later.walk_phase_rad - first.walk_phase_rad == pytest.approx(np.pi, abs=0.35)
            assert moved > 0.1  # the legs swapped sides: feet tens of centimetres apart
        else:
            assert moved == 0.0
    assert HIP_SWING_RAD > 0


def test_convex_parts_cover_the_model():
    """The collision compound: each wheel its own piece, the body in slabs, every vertex in
    some piece."""
    model = agent_model(AgentClass.CAR, "sedan", (4.6, 1.85, 1.45), "c")
    parts = convex_parts(model)
    assert len(parts) >= 4 + 4  # four wheels, body slabs
    covered = np.concatenate(parts)
    assert len(np.unique(np.round(covered, 4), axis=0)) == len(
        np.unique(np.round(model.positions.astype(np.float64), 4), axis=0)
    )


def _plain_look(direction=(0.0, 0.0, 1.0), shadows=False) -> ShaderLook:
    return ShaderLook(
        light_direction=tuple(float(v) for v in np.asarray(direction) / np.linalg.norm(direction)),
        sun_rgb=(0.6, 0.6, 0.6), sky_ambient=(0.4, 0.4, 0.4), ground_ambient=(0.4, 0.4, 0.4),
        zenith_rgb=(0.7, 0.78, 0.9), horizon_rgb=(0.7, 0.78, 0.9), cloud_cover=0.0,
        cloud_rgb=(1.0, 1.0, 1.0), sun_disc=0.0, shadows=shadows, fog_rgb=(0.8, 0.8, 0.8),
        fog_density=0.0, wetness=0.0, lamps_on=False, headlights=False,
    )  # fmt: skip


@pytest.fixture
def client():
    import pybullet

    handle = pybullet.connect(pybullet.DIRECT)
    yield pybullet, handle
    pybullet.disconnect(handle)


def _actor(p, handle: int) -> int:
    shape = p.createVisualShape(p.GEOM_BOX, halfExtents=[0.1, 0.1, 0.1], physicsClientId=handle)
    return p.createMultiBody(0, -1, shape, [0, 0, 0], physicsClientId=handle)


@needs_gl
def test_a_braking_car_shows_lit_brake_light_pixels_and_a_cruising_one_does_not(client):
    p, handle = client
    body = _actor(p, handle)
    p.resetBasePositionAndOrientation(body, [10, 0, 0.725], [0, 0, 0, 1], physicsClientId=handle)
    model = agent_model(AgentClass.CAR, "sedan", (4.6, 1.85, 1.45), "brake-test")
    assert (model.lights == Light.TAIL).any()
    renderer = GLRenderer(p, handle, [], _plain_look())
    renderer.set_models({body: model})
    view = p.computeViewMatrix([0, 0, 1.2], [10, 0, 0.7], [0, 0, 1], physicsClientId=handle)
    projection = p.computeProjectionMatrixFOV(30.0, 4 / 3, 0.5, 200.0, physicsClientId=handle)
    lit = {}
    for state, brake in ((1, False), (2, True)):
        renderer.sync(state, {body: Animation(brake=brake)})
        rgb, _, _ = renderer.draw(view, projection, 160, 120, False, 200.0)
        red = (rgb[..., 0] > 200) & (rgb[..., 1] < 60) & (rgb[..., 2] < 60)
        lit[brake] = int(red.sum())
    renderer.release()
    assert lit[True] >= 6 and lit[False] == 0


@needs_gl
def test_a_building_casts_its_shadow_away_from_the_sun(client):
    """A 10 m cube on a ground plane, the sun low in the east: the ground west of it is in
    shadow, the ground east of it in the sun."""
    p, handle = client
    ground = TwinMesh(1000, "ground", (0.5, 0.5, 0.5, 1.0), 0, *_quad(60.0), None)
    vertices, indices = box_mesh(np.array([0.0, 0.0, 5.0]), 0.0, np.array([10.0, 10.0, 10.0]))
    building = TwinMesh(1001, "building", (0.6, 0.6, 0.6, 1.0), 0, vertices, indices, None)
    renderer = GLRenderer(p, handle, [ground, building], _plain_look((1.0, 0.0, 0.8), shadows=True))
    renderer.sync(1)
    view = p.computeViewMatrix([0, 0, 120], [0, 0, 0], [0, 1, 0], physicsClientId=handle)
    projection = p.computeProjectionMatrixFOV(30.0, 1.0, 50.0, 200.0, physicsClientId=handle)
    rgb, _, body = renderer.draw(view, projection, 128, 128, True, 200.0)
    renderer.release()
    grey = rgb.mean(axis=2)
    # image columns run west to east (x), rows north to south; the cube spans about +-10 px
    row = 64
    west = grey[row, 30:44][body[row, 30:44] == 1000 - 0]
    east = grey[row, 84:98][body[row, 84:98] == 1000 - 0]
    assert len(west) and len(east)
    assert west.mean() < 0.75 * east.mean()


def _quad(half: float):
    vertices = np.array(
        [[-half, -half, 0.0], [half, -half, 0.0], [half, half, 0.0], [-half, half, 0.0]]
    )
    return vertices, np.array([0, 1, 2, 0, 2, 3])


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    from tests.factories import synthetic_clip

    return synthetic_clip(tmp_path_factory.mktemp("models_site"))


@needs_gl
def test_instance_pixels_lie_inside_the_projected_box(site):
    """Every pixel an agent's model covers in the six cameras lies inside its box's projection
    (the box stays the label): the models fill their boxes and never leave them."""
    from dataclasses import replace

    import shapely

    from drivee2e_data.sensors.annotate import box_corners_3d, projected_area
    from drivee2e_data.sensors.camera import render
    from drivee2e_data.sensors.ego_state import ego_motion
    from drivee2e_data.sensors.rig import default_rig
    from drivee2e_data.sim.world import World

    intersection_map, scenario = site
    checked = 0
    with World(intersection_map, scenario, renderer="gl") as world:
        ego = scenario.ego
        motion = ego_motion(scenario)
        for frame in (20, 60):
            world.place_ego(float(ego.x_m[frame]), float(ego.y_m[frame]), ego.track_id)
            world.set_time(frame)
            ego_to_world = motion.ego_to_world(frame)
            for camera in default_rig().cameras:
                view = render(world, replace(camera, width=400, height=225), ego_to_world)
                for track in scenario.tracks:
                    body = world.bodies[track.track_id]
                    rows, columns = np.nonzero(view.mask == body)
                    if len(rows) < 5:
                        continue
                    corners = box_corners_3d(track, frame, world.blueprints[track.track_id].size_m)
                    area = projected_area(view, corners, ego_to_world).buffer(1.0)
                    points = shapely.points(columns + 0.5, rows + 0.5)
                    assert shapely.contains(area, points).all(), (track.track_id, camera.name)
                    checked += 1
    assert checked >= 5
