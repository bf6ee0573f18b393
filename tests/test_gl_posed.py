"""The actors' models posed on the GPU (`gl_posed`): the texels a vertex reads place it where the
CPU's placing does, and a frame drawn that way is the frame posed on the CPU."""

from __future__ import annotations

import numpy as np
import pytest

from drivee2e_data.scenario import AgentClass
from drivee2e_data.sim import gl_context
from drivee2e_data.sim.gl_context import gl_available
from drivee2e_data.sim.gl_posed import (
    JOINTS_PER_ROW,
    JointTable,
    PosedModels,
    joint_texels,
    model_vertices,
)
from drivee2e_data.sim.gl_vertices import PlacedModel
from drivee2e_data.sim.models import Animation, agent_model
from drivee2e_data.sim.world import World
from tests.factories import JOINTED_MODELS, front_view, pose_on_cpu, synthetic_clip


def _shaded(vertices: np.ndarray, texels: np.ndarray, first_joint: int) -> np.ndarray:
    """What `shaders/posed.glsl` makes of `model_vertices` rows, in numpy: world positions,
    normals and emission `(N, 7)`."""
    rows = texels[vertices[:, 3].astype(np.int64) - first_joint]  # (N, 4, 4)
    point = np.concatenate([vertices[:, 0:3], np.ones((len(vertices), 1), np.float32)], axis=1)
    position = np.einsum("nij,nj->ni", rows[:, 0:3, :], point)
    normal = np.einsum("nij,nj->ni", rows[:, 0:3, 0:3], vertices[:, 4:7])
    kind = vertices[:, 11].astype(np.int64)
    levels = np.stack([np.zeros(len(rows)), rows[:, 3, 0], rows[:, 3, 1]], axis=1)
    emission = levels[np.arange(len(rows)), kind]
    return np.concatenate([position, normal, emission[:, None]], axis=1)


@pytest.mark.parametrize(
    ("agent_class", "name", "size"),
    JOINTED_MODELS,
)
@pytest.mark.parametrize("lights", [(False, False), (True, False), (True, True)])
def test_a_vertex_read_through_its_joints_texels_lands_where_the_cpu_places_it(
    agent_class, name, size, lights
):
    """Each vertex moved by its joint's texels (the shader's arithmetic, here in numpy) is the
    vertex `PlacedModel` places for the same animation and body pose, within float32 rounding:
    position, normal and emission (headlights, tail lights dim or braking), with the model's
    colours, body id and materials carried as they are."""
    model = agent_model(agent_class, name, size, "posed")
    headlights, brake = lights
    animation = Animation(wheel_angle_rad=2.1, steer_rad=0.15, walk_phase_rad=1.3,
                          walk_amount=0.8, brake=brake, headlights=headlights)  # fmt: skip
    yaw, position = 0.7, (12.0, -3.0, 0.4)
    quaternion = (0.0, 0.0, float(np.sin(yaw / 2)), float(np.cos(yaw / 2)))
    first_joint = 2 * JOINTS_PER_ROW + 3  # a joint row past the texture's first line
    vertices = model_vertices(model, body=7, first_joint=first_joint)
    texels = joint_texels(model, animation, position, quaternion)
    shaded = _shaded(vertices, texels, first_joint)
    placer = PlacedModel(model, body=7)
    placed = placer.vertices(animation, position, quaternion)  # in joint order
    order = placer.order
    assert np.allclose(shaded[order, 0:3], placed[:, 0:3], atol=2e-5)
    assert np.allclose(shaded[order, 3:6], placed[:, 3:6], atol=2e-6)
    assert np.array_equal(shaded[order, 6].astype(np.float32), placed[:, 10])
    assert np.array_equal(vertices[order, 7:10], placed[:, 6:9])  # colours
    assert np.all(vertices[:, 10] == 8)  # body id + 1
    assert np.array_equal(vertices[order, 12], placed[:, 11])  # materials
    lit = (headlights or brake) and bool((np.asarray(model.lights) > 0).any())
    assert (shaded[:, 6] > 0).any() == lit


def test_many_models_posed_at_once_are_each_posed_alone():
    """`JointTable` poses every model of a state in one go: each model's texels are the ones
    `joint_texels` gives it alone (`joint_transforms`, `placed_joints`), for cars, buses,
    walkers, every kind of rider and joint, at poses and animations that differ per model."""
    from drivee2e_data.sim.actors import BLUEPRINTS

    rng = np.random.default_rng(4)
    models, animations, positions, quaternions = [], [], [], []
    for agent_class, blueprints in BLUEPRINTS.items():
        for name, length, width, height in blueprints[:2]:
            models.append(agent_model(agent_class, name, (length, width, height), name))
            animations.append(Animation(
                wheel_angle_rad=float(rng.uniform(-9, 9)), steer_rad=float(rng.uniform(-0.4, 0.4)),
                walk_phase_rad=float(rng.uniform(0, 7)), walk_amount=float(rng.uniform(0, 1)),
                brake=bool(rng.integers(2)), headlights=bool(rng.integers(2))))  # fmt: skip
            positions.append(rng.uniform(-50, 50, 3))
            yaw = rng.uniform(-np.pi, np.pi)
            quaternions.append((0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)))
    kinds = {joint.kind for model in models for joint in model.joint_table}
    assert kinds == {"root", "wheel", "steer_wheel", "hip", "knee", "ankle", "shoulder",
                     "elbow", "pedal"}  # fmt: skip
    together = JointTable(models).texels(np.array(positions), np.array(quaternions), animations)
    first = 0
    for model, animation, position, quaternion in zip(
        models, animations, positions, quaternions, strict=True
    ):
        alone = joint_texels(model, animation, position, quaternion)
        assert np.allclose(together[first : first + len(alone)], alone, atol=1e-5)
        first += len(alone)
    assert first == len(together)


@pytest.mark.skipif(not gl_available(), reason="no OpenGL context (EGL) here")
def test_a_shown_models_batch_holds_it_and_a_hidden_model_collapses_to_a_point():
    """After `pose`, a batch per shown model in buffer order, each box holding the model's
    posed vertices (what a view's frustum test relies on); a model not shown has every joint's
    transform zero, so a run drawn across it (joined over a gap) puts no triangle anywhere."""
    sizes = {3: (AgentClass.CAR, "sedan", (4.6, 1.85, 1.45)),
             5: (AgentClass.PEDESTRIAN, "pedestrian", (0.6, 0.6, 1.72)),
             9: (AgentClass.CYCLIST, "bicycle", (1.8, 0.6, 1.7))}  # fmt: skip
    models = {body: agent_model(*size, f"m{body}") for body, size in sizes.items()}
    animation = Animation(wheel_angle_rad=1.0, steer_rad=0.2, walk_phase_rad=2.0,
                          walk_amount=1.0)  # fmt: skip
    quaternion = (0.0, 0.0, float(np.sin(0.4)), float(np.cos(0.4)))
    places = {3: (10.0, 5.0, 0.7), 9: (-20.0, 3.0, 0.85)}
    context = gl_context.context()
    with gl_context.current(context):
        posed = PosedModels(context, models)
        try:
            posed.pose([(body, places[body], quaternion, animation) for body in (9, 3)])
            batches = posed.batches
            assert batches.first.tolist() == [posed.ranges[3][0], posed.ranges[9][0]]
            for k, body in enumerate((3, 9)):
                _, count, first_joint = posed.ranges[body]
                vertices = model_vertices(models[body], body, first_joint)
                placed = _shaded(vertices, posed.texels[first_joint:], first_joint)[:, 0:3]
                assert count == len(vertices) == batches.count[k]
                assert np.all(placed >= batches.low_m[k]) and np.all(placed <= batches.high_m[k])
            first_joint = posed.ranges[5][2]
            hidden = posed.texels[first_joint : first_joint + len(models[5].joint_table)]
            assert not hidden.any()
        finally:
            posed.release()


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    return synthetic_clip(tmp_path_factory.mktemp("posed_site"))


@pytest.mark.skipif(not gl_available(), reason="no OpenGL context (EGL) here")
def test_frames_posed_on_the_gpu_are_the_frames_posed_on_the_cpu(site, monkeypatch):
    """A GPU host's renderer poses the actors in its vertex shader; frames of the
    same clip drawn that way and with the models posed on the CPU show the same bodies at the
    same pixels, depths to a centimetre, and colours the same but on a few edge pixels (the
    shader's and numpy's float32 products round apart), before and after a replay; so does a
    depth-and-ids view (the labels program posed too)."""
    intersection_map, scenario = site
    monkeypatch.setattr(gl_context, "rasterises_on_cpu", lambda: False)
    frames = (5, 40, 80)
    images = {}
    for on_gpu in (True, False):
        with World(intersection_map, scenario, renderer="gl") as world:
            if not on_gpu:
                pose_on_cpu(world)
            actor_bodies = set(world.bodies.values())
            images[on_gpu] = [front_view(world, f, (320, 180), segmentation=True, near_m=0.5)
                              for f in frames]  # fmt: skip
            # the depth-and-ids view the LiDAR and the boxes' visibility read
            images[on_gpu].append(front_view(world, frames[1], (320, 180), segmentation=True,
                                             near_m=0.5, look="labels"))  # fmt: skip
            if on_gpu:
                posed = world.gl.posed
                assert posed is not None and len(posed.batches.first) > 0
                # the CPU placed no model but the hidden ego's, which casts its shadow alone
                assert set(world.gl.placed) == {world.bodies[scenario.ego.track_id]}
                world.replay(scenario)
                assert world.gl.posed is not posed  # the new clip's models
                again = front_view(world, frames[-1], (320, 180), segmentation=True, near_m=0.5)
                assert np.array_equal(again.rgb, images[True][len(frames) - 1].rgb)
    actors = 0
    for gpu, cpu in zip(images[True], images[False], strict=True):
        assert np.array_equal(gpu.segmentation, cpu.segmentation)
        assert np.abs(gpu.depth_m - cpu.depth_m).max() < 0.01
        apart = np.abs(gpu.rgb.astype(int) - cpu.rgb.astype(int)).max(axis=2) > 1
        assert apart.mean() < 1e-3
        actors += len(set(np.unique(gpu.segmentation).tolist()) & actor_bodies)
    assert actors >= 3  # the frames show actors at all
