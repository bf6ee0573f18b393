"""How the GL renderer spends a pixel's work: draws grouped by material (each group's shader holds
only its materials' code), and the headlights' light read from a raster remade per state."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivee2e_data.sim.conditions import (
    HEADLIGHT_CONE_COS,
    HEADLIGHT_GAIN,
    LampRaster,
    ShaderLook,
    headlight_raster,
)
from drivee2e_data.sim.gl_batches import MATERIAL_GROUPS, group_defines, in_draw_order
from drivee2e_data.sim.gl_context import current, gl_available
from drivee2e_data.sim.gl_renderer import GLRenderer, SceneLights
from drivee2e_data.sim.gl_vertices import FLOATS_PER_VERTEX
from drivee2e_data.sim.models import Material
from drivee2e_data.sim.twin_plan import TwinMesh

needs_gl = pytest.mark.skipif(not gl_available(), reason="no OpenGL context (EGL) here")


def _triangles(materials: list[int]) -> np.ndarray:
    """One triangle per material, its first float numbering it (to follow it when sorted)."""
    rows = np.zeros((3 * len(materials), FLOATS_PER_VERTEX), np.float32)
    for k, material in enumerate(materials):
        rows[3 * k : 3 * k + 3, 0] = k
        rows[3 * k : 3 * k + 3, -1] = material
    return rows


def test_triangles_are_grouped_by_material_in_the_order_groups_first_appear():
    M = Material
    materials = [M.ASPHALT, M.PAINT, M.MARKING, M.ASPHALT, M.GLASS, M.FACADE, M.MARKING, 99]
    grouped, batches = in_draw_order(_triangles(materials))
    ranges = batches.groups
    order = grouped[::3, 0].astype(int).tolist()
    # asphalt's group first (it came first), then paint and glass (one group), markings,
    # facades, then the unknown code; within a group the triangles keep their order
    assert order == [0, 3, 1, 4, 2, 6, 5, 7]
    assert [(first, count) for _, first, count in ranges] == [
        (0, 6), (6, 6), (12, 6), (18, 3), (21, 3)
    ]  # fmt: skip
    groups = [group for group, _, _ in ranges]
    assert groups[-1] == len(MATERIAL_GROUPS)  # codes outside every group: all the code
    assert "HAS_ASPHALT" in group_defines(groups[0], ("NIGHT",))
    assert group_defines(groups[0], ())[-1] == "HAS_ASPHALT"
    assert "GLOSSY" not in group_defines(groups[0], ()) and "GLOSSY" in group_defines(
        groups[0], ("WET",)
    )  # wet ground shines
    assert set(group_defines(groups[-1], ())) >= {"HAS_FACADE", "HAS_FOLIAGE", "GLOSSY"}
    np.testing.assert_array_equal(np.sort(grouped[:, 0]), np.sort(_triangles(materials)[:, 0]))


def test_a_headlights_light_on_the_ground_is_known_ahead_and_nothing_behind():
    raster = LampRaster((-50.0, -50.0), 0.5, np.zeros((200, 200), np.float32))
    spot = ((0.0, 0.0, 0.7), (1.0, 0.0, 0.0))  # level, along +x
    values = headlight_raster([spot], raster, reach_m=45.0)

    def at(x: float, y: float) -> float:  # the cell whose centre is (x, y)
        return float(values[int((y + 50.0) / 0.5), int((x + 50.0) / 0.5)])

    x, y = 10.25, 0.25  # a cell centre 10.25 m ahead
    distance = math.sqrt(x * x + y * y + 0.7 * 0.7)
    aim = x / distance
    low, high = HEADLIGHT_CONE_COS
    t = min(max((aim - low) / (high - low), 0.0), 1.0)
    expected = HEADLIGHT_GAIN * t * t * (3 - 2 * t) * (1 - distance / 45.0) ** 2
    expected *= (0.7 / distance + 0.6) / 1.6
    assert at(x, y) == pytest.approx(expected, rel=1e-5)
    assert at(-10.25, 0.25) == 0.0  # behind the lamp
    assert at(10.25, 10.25) == 0.0  # 45 degrees off the beam: outside the cone
    assert at(46.25, 0.25) == 0.0  # beyond the reach
    assert values[0].max() == values[-1].max() == values[:, 0].max() == values[:, -1].max() == 0
    # two lamps add up
    twice = headlight_raster([spot, spot], raster, reach_m=45.0)
    np.testing.assert_allclose(twice, 2 * values, rtol=1e-6)


def _night_look(headlights: bool) -> ShaderLook:
    return ShaderLook(
        light_direction=(0.0, 0.0, 1.0), sun_rgb=(0.0, 0.0, 0.0), sky_ambient=(0.02, 0.02, 0.02),
        ground_ambient=(0.02, 0.02, 0.02), zenith_rgb=(0.0, 0.0, 0.05), horizon_rgb=(0.0, 0.0, 0.05),
        cloud_cover=0.0, cloud_rgb=(1.0, 1.0, 1.0), sun_disc=0.0, shadows=False,
        fog_rgb=(0.0, 0.0, 0.0), fog_density=0.0, wetness=0.0, lamps_on=True, headlights=headlights,
    )  # fmt: skip


def _grey_ground(half_m: float = 60.0) -> TwinMesh:
    """A grey square of ground `2 half_m` wide around the origin."""
    vertices = np.array([[-half_m, -half_m, 0.0], [half_m, -half_m, 0.0], [half_m, half_m, 0.0],
                         [-half_m, half_m, 0.0]])  # fmt: skip
    return TwinMesh(1000, "ground", (0.5, 0.5, 0.5, 1.0), Material.MATTE, vertices,
                    np.array([0, 1, 2, 0, 2, 3]), None)  # fmt: skip


@needs_gl
def test_at_night_a_headlight_lights_the_road_ahead_of_it_only():
    """A grey ground at night under no street lamp, one car's beam from (0, 0) along +x: seen
    from above, the road 10 m ahead is lit, 10 m behind is not, and nothing is lit when the
    look has no headlights."""
    import pybullet as p

    handle = p.connect(p.DIRECT)
    try:
        ground = _grey_ground()
        lamps = [(-40.0, -40.0, 8.0), (40.0, 40.0, 8.0)]  # far corners: the raster spans the site
        spot = SceneLights(headlights=(((0.0, 0.0, 0.7), (1.0, 0.0, 0.0)),))
        view = p.computeViewMatrix([0, 0, 100], [0, 0, 0], [0, 1, 0], physicsClientId=handle)
        projection = p.computeProjectionMatrixFOV(30.0, 1.0, 50.0, 200.0, physicsClientId=handle)
        grey = {}
        for headlights in (True, False):
            renderer = GLRenderer(p, handle, [ground], _night_look(headlights), street_lamps=lamps)
            renderer.sync(1, lights=spot)
            rgb, _, _ = renderer.draw(view, projection, 128, 128, False, 200.0)
            renderer.release()
            grey[headlights] = rgb.mean(axis=2)
        # 128 px over 2 x 100 tan(15 deg) = 53.6 m: 2.39 px a metre; x runs along the columns
        row, ahead, behind = 64, 64 + 24, 64 - 24
        assert grey[True][row, ahead] > grey[False][row, ahead] + 40
        assert grey[True][row, behind] == pytest.approx(grey[False][row, behind], abs=1)
        assert grey[False][row, ahead] == pytest.approx(grey[False][row, behind], abs=1)
    finally:
        p.disconnect(handle)


@needs_gl
def test_lights_that_change_while_the_bodies_stand_still_are_drawn():
    """A closed-loop step shows its scene before the ego is placed (`sync_bodies`), then takes
    the lights the ego's place gives (`sync` at the same state): a beam taken that way lights
    the road, one taken away leaves it dark, and lights equal to the last ones are not taken
    again (the light texture and the shadow map keyed by `drawn_state`)."""
    import pybullet as p

    handle = p.connect(p.DIRECT)
    try:
        lamps = [(-40.0, -40.0, 8.0), (40.0, 40.0, 8.0)]
        beam = (((0.0, 0.0, 0.7), (1.0, 0.0, 0.0)),)
        view = p.computeViewMatrix([0, 0, 100], [0, 0, 0], [0, 1, 0], physicsClientId=handle)
        projection = p.computeProjectionMatrixFOV(30.0, 1.0, 50.0, 200.0, physicsClientId=handle)
        renderer = GLRenderer(p, handle, [_grey_ground()], _night_look(True), street_lamps=lamps)
        try:
            grey = []
            renderer.sync_bodies(1)
            for lights in (SceneLights(), SceneLights(headlights=beam), SceneLights()):
                renderer.sync(1, lights=lights)  # the bodies' state the same throughout
                rgb, _, _ = renderer.draw(view, projection, 128, 128, False, 200.0)
                grey.append(rgb.mean(axis=2)[64, 64 + 24])  # 10 m ahead of the beam
            taken = renderer.drawn_state
            renderer.sync(1, lights=SceneLights())  # equal to the last: nothing taken
            assert renderer.drawn_state == taken
            renderer.sync_bodies(2)  # the bodies again: the same lights are taken after them
            renderer.sync(2, lights=renderer.lights)
            assert renderer.drawn_state == (2, taken[1] + 1)
        finally:
            renderer.release()
        assert grey[1] > grey[0] + 40
        assert grey[2] == pytest.approx(grey[0], abs=1)
    finally:
        p.disconnect(handle)


@needs_gl
def test_bodies_removed_and_forgotten_leave_nothing_of_theirs_to_draw():
    """A moving body synced, then removed and its renderer told (`forget_bodies`, as a world
    replaying another clip does): the next sync has no moving vertices, even when it finds no
    moving body at all (an order kept by its parts' ids must not outlive the bodies)."""
    import pybullet as p

    handle = p.connect(p.DIRECT)
    try:
        shape = p.createVisualShape(p.GEOM_BOX, halfExtents=[1, 1, 1], physicsClientId=handle)
        box = p.createMultiBody(baseVisualShapeIndex=shape, basePosition=[0, 0, 1],
                                physicsClientId=handle)  # fmt: skip
        renderer = GLRenderer(p, handle, [_grey_ground()], _night_look(False))
        try:
            renderer.sync(1)
            assert len(renderer.dynamic_ordered[0]) == 12 * 3  # a box: 12 triangles
            p.removeBody(box, physicsClientId=handle)
            renderer.forget_bodies()
            renderer.sync(2)
            assert len(renderer.dynamic_ordered[0]) == 0
        finally:
            renderer.release()
    finally:
        p.disconnect(handle)


@needs_gl
def test_the_light_texture_made_again_only_where_beams_were_or_are_is_the_whole_raster():
    """From one state to the next the renderer remakes and writes only the box of the beams
    before and after: after each state (beams moving, none, back again) the texture holds the
    lamps' raster and `headlight_raster` of that state's beams, as made whole."""
    import pybullet as p

    handle = p.connect(p.DIRECT)
    try:
        ground = _grey_ground()
        lamps = [(-40.0, -40.0, 8.0), (40.0, 40.0, 8.0), (-40.0, 40.0, 8.0)]
        view = p.computeViewMatrix([0, 0, 100], [0, 0, 0], [0, 1, 0], physicsClientId=handle)
        projection = p.computeProjectionMatrixFOV(30.0, 1.0, 50.0, 200.0, physicsClientId=handle)
        look = _night_look(True)
        renderer = GLRenderer(p, handle, [ground], look, street_lamps=lamps)
        states = [
            (((0.0, 0.0, 0.7), (1.0, 0.0, 0.0)),),
            (((10.0, 5.0, 0.7), (0.0, 1.0, 0.0)), ((-20.0, 0.0, 0.7), (-1.0, 0.0, 0.0))),
            (),
            (((30.0, -30.0, 0.7), (0.6, 0.8, 0.0)),),
        ]
        try:
            for state, spots in enumerate(states, start=1):
                renderer.sync(state, lights=SceneLights(headlights=spots))
                renderer.draw(view, projection, 64, 64, False, 200.0)
                raster = renderer._lamp_raster()
                shape = (*raster.values.shape, 2)
                with current(renderer.context):  # another test's context may be current
                    held = renderer.lamp_texture.read()
                held = np.frombuffer(held, np.float32).reshape(shape)
                assert np.array_equal(held[..., 0], raster.values)
                assert np.array_equal(held[..., 1], headlight_raster(spots, raster)), state
                assert (held[..., 1] > 0).any() == bool(spots)
        finally:
            renderer.release()
    finally:
        p.disconnect(handle)


def test_a_union_of_boxes_holds_both_and_no_box_is_none():
    from drivee2e_data.sim.conditions import box_union

    assert box_union(None, None) is None
    assert box_union((1, 4, 2, 6), None) == (1, 4, 2, 6)
    assert box_union(None, (1, 4, 2, 6)) == (1, 4, 2, 6)
    assert box_union((1, 4, 2, 6), (3, 9, 0, 5)) == (1, 9, 0, 6)
