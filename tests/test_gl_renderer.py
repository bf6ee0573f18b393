"""The GL renderer: known depths and body ids, moving bodies, agreement with pybullet's own EGL
renderer, and the same image every time."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from drivee2e_data.sim import gl_context, gl_renderer
from drivee2e_data.sim.conditions import ShaderLook
from drivee2e_data.sim.gl_context import gl_available
from drivee2e_data.sim.gl_renderer import GLRenderer
from drivee2e_data.sim.gl_vertices import read_obj
from drivee2e_data.sim.world import World
from tests.factories import egl_world, front_view, synthetic_clip

pytestmark = pytest.mark.skipif(not gl_available(), reason="no OpenGL context (EGL) here")
SKY_RGB = (0.70, 0.78, 0.90)
# the sun straight above, ambient 0.5 from every side, a plain sky of one colour, no weather
NOON = ShaderLook(
    light_direction=(0.0, 0.0, 1.0), sun_rgb=(0.5, 0.5, 0.5), sky_ambient=(0.5, 0.5, 0.5),
    ground_ambient=(0.5, 0.5, 0.5), zenith_rgb=SKY_RGB, horizon_rgb=SKY_RGB, cloud_cover=0.0,
    cloud_rgb=(1.0, 1.0, 1.0), sun_disc=0.0, shadows=False, fog_rgb=(0.8, 0.8, 0.8),
    fog_density=0.0, wetness=0.0, lamps_on=False, headlights=False,
)  # fmt: skip
NEAR_M, FAR_M = 0.5, 200.0


@pytest.fixture
def box_scene():
    """A pybullet client with a 2 m cube centred 20 m along +x, 1 m up, and a GL renderer of it
    (the cube moving: not static)."""
    import pybullet

    client = pybullet.connect(pybullet.DIRECT)
    shape = pybullet.createVisualShape(
        pybullet.GEOM_BOX, halfExtents=[1, 1, 1], rgbaColor=[1, 0, 0, 1], physicsClientId=client
    )
    cube = pybullet.createMultiBody(0, -1, shape, [20, 0, 1], physicsClientId=client)
    renderer = GLRenderer(pybullet, client, [], NOON)
    yield pybullet, client, cube, renderer
    renderer.release()
    pybullet.disconnect(client)


def _look_along_x(p, client: int, size=(64, 48)):
    view = p.computeViewMatrix([0, 0, 1], [1, 0, 1], [0, 0, 1], physicsClientId=client)
    projection = p.computeProjectionMatrixFOV(30.0, size[0] / size[1], NEAR_M, FAR_M,
                                              physicsClientId=client)  # fmt: skip
    return view, projection


def test_a_cube_20_m_ahead_reads_19_m_to_its_face_with_its_body_id(box_scene):
    p, client, cube, renderer = box_scene
    renderer.sync(1)
    rgb, depth, body = renderer.draw(*_look_along_x(p, client), 64, 48, True, FAR_M)
    assert rgb.shape == (48, 64, 3) and depth.shape == body.shape == (48, 64)
    assert depth[24, 32] == pytest.approx(19.0, abs=1e-4) and depth[0, 0] == FAR_M
    assert body[24, 32] == cube and body[0, 0] == -1  # the sky is no body
    assert np.array_equal(rgb[0, 0], np.round(np.array(SKY_RGB) * 255).astype(np.uint8))
    # the face looks at -x, the light from above: ambient only, red
    assert rgb[24, 32, 0] == pytest.approx(0.5 * 255, abs=1) and rgb[24, 32, 1:].max() == 0
    # row 0 is the top: the cube spans z 0..2 around the eye's 1 m, so rows above and below it
    # at its silhouette show sky on top; the ground side below is sky as well (no ground here)
    assert body[:, 32].tolist().count(cube) > 0 and body[0, 32] == -1


def test_a_moved_body_is_drawn_where_it_went_after_a_sync(box_scene):
    p, client, cube, renderer = box_scene
    view, projection = _look_along_x(p, client)
    renderer.sync(1)
    before = renderer.draw(view, projection, 64, 48, False, FAR_M)[1]
    p.resetBasePositionAndOrientation(cube, [10, 0, 1], [0, 0, 0, 1], physicsClientId=client)
    renderer.sync(1)  # the same state: nothing is read again
    assert np.array_equal(renderer.draw(view, projection, 64, 48, False, FAR_M)[1], before)
    renderer.sync(2)
    after = renderer.draw(view, projection, 64, 48, False, FAR_M)[1]
    assert after[24, 32] == pytest.approx(9.0, abs=1e-4)


def test_a_lamp_shines_its_colour_with_the_sun_behind_it(box_scene):
    """Signal lamps are unshaded: lit from behind, a red lamp still reads pure red, while the
    cube beside it, a plain body, gets the ambient share only."""
    p, client, cube, _ = box_scene
    shape = p.createVisualShape(p.GEOM_SPHERE, radius=0.5, rgbaColor=[1, 0, 0, 1],
                                physicsClientId=client)  # fmt: skip
    lamp = p.createMultiBody(0, -1, shape, [10, 0, 1], physicsClientId=client)
    p.resetBasePositionAndOrientation(cube, [20, 3, 1], [0, 0, 0, 1], physicsClientId=client)
    behind = replace(NOON, light_direction=(1.0, 0.0, 0.0))
    renderer = GLRenderer(p, client, [], behind, lamps=[lamp])
    renderer.sync(1)
    view = p.computeViewMatrix([0, 0, 1], [1, 0, 1], [0, 0, 1], physicsClientId=client)
    projection = p.computeProjectionMatrixFOV(40.0, 1.0, NEAR_M, FAR_M, physicsClientId=client)
    rgb, _, body = renderer.draw(view, projection, 64, 64, True, FAR_M)
    renderer.release()
    assert body[32, 32] == lamp and rgb[32, 32].tolist() == [255, 0, 0]
    cube_pixels = rgb[body == cube]
    assert len(cube_pixels) and np.abs(cube_pixels[:, 0].astype(int) - 128).max() <= 1


def test_still_lamps_are_not_ordered_or_written_again_until_one_changes_colour(box_scene):
    """A new state whose moving bodies all stand as before, in the same colours, keeps the
    moving bodies' vertices in draw order as they were (no order, no upload); a lamp turned
    green is drawn green; a moved body is ordered again."""
    p, client, cube, _ = box_scene
    shape = p.createVisualShape(p.GEOM_SPHERE, radius=0.5, rgbaColor=[1, 0, 0, 1],
                                physicsClientId=client)  # fmt: skip
    lamp = p.createMultiBody(0, -1, shape, [10, 0, 1], physicsClientId=client)
    p.resetBasePositionAndOrientation(cube, [20, 3, 1], [0, 0, 0, 1], physicsClientId=client)
    renderer = GLRenderer(p, client, [], NOON, lamps=[lamp])
    view = p.computeViewMatrix([0, 0, 1], [1, 0, 1], [0, 0, 1], physicsClientId=client)
    projection = p.computeProjectionMatrixFOV(40.0, 1.0, NEAR_M, FAR_M, physicsClientId=client)
    renderer.sync(1)
    first = renderer.dynamic_ordered
    red = renderer.draw(view, projection, 64, 64, True, FAR_M)
    renderer.sync(2)  # nothing moved or changed colour
    assert renderer.dynamic_ordered is first
    again = renderer.draw(view, projection, 64, 64, True, FAR_M)
    assert all(np.array_equal(a, b) for a, b in zip(red, again, strict=True))
    p.changeVisualShape(lamp, -1, rgbaColor=[0, 1, 0, 1], physicsClientId=client)
    renderer.sync(3)
    green = renderer.dynamic_ordered
    rgb, _, body = renderer.draw(view, projection, 64, 64, True, FAR_M)
    assert green is not first and body[32, 32] == lamp and rgb[32, 32].tolist() == [0, 255, 0]
    p.resetBasePositionAndOrientation(cube, [20, -3, 1], [0, 0, 0, 1], physicsClientId=client)
    renderer.sync(4)  # a body moved
    assert renderer.dynamic_ordered is not green
    _, _, body = renderer.draw(view, projection, 64, 64, True, FAR_M)
    assert (body == cube)[:, 33:].any() and not (body == cube)[:, :31].any()  # now to the right
    renderer.release()


def test_obj_files_read_as_the_twin_writes_them(tmp_path):
    path = tmp_path / "quad.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n")
    positions, normals = read_obj(path)
    assert positions.shape == normals.shape == (6, 3)
    assert np.allclose(normals, [0, 0, 1])  # counter-clockwise from above: facing up


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    return synthetic_clip(tmp_path_factory.mktemp("gl_site"))


def _front(world: World, frame: int, segmentation: bool = True):
    return front_view(world, frame, (320, 180), segmentation=segmentation, near_m=0.5)


def _eye_at(world: World, frame: int) -> np.ndarray:
    """The frame's scene set, the ego hidden at its logged place; a point 1.6 m above it."""
    ego = world.scenario.ego
    world.place_ego(float(ego.x_m[frame]), float(ego.y_m[frame]), ego.track_id)
    world.set_time(frame)
    return np.array([ego.x_m[frame], ego.y_m[frame], 1.6])


def test_the_gl_world_draws_what_pybullets_egl_renderer_draws(site):
    """The same bodies where pybullet's own renderer puts them: body masks agree on 97% of the
    pixels or more (the rest are silhouettes), depths to 0.5% where both see the same body."""
    intersection_map, scenario = site
    reference = egl_world(intersection_map, scenario)
    with reference:
        for frame in (0, 30):  # pybullet's first EGL draws still upload meshes (bench_render.py)
            _front(reference, frame)
        expected = [_front(reference, frame) for frame in (0, 30)]
        with World(intersection_map, scenario, renderer="gl") as world:
            drawn = [_front(world, frame) for frame in (0, 30)]
            # and the EGL world still draws correctly after the GL one did (contexts restored)
            assert np.array_equal(_front(reference, 0).segmentation, expected[0].segmentation)
    for ours, theirs in zip(drawn, expected, strict=True):
        same = ours.segmentation == theirs.segmentation
        assert same.mean() >= 0.97
        seen = same & (ours.segmentation >= 0)
        relative = np.abs(ours.depth_m[seen] - theirs.depth_m[seen]) / theirs.depth_m[seen]
        assert np.median(relative) < 0.005


def test_the_same_frame_is_the_same_image_twice_and_in_another_world(site):
    intersection_map, scenario = site
    with World(intersection_map, scenario, renderer="gl") as world:
        first = _front(world, 20)
        _front(world, 40)
        again = _front(world, 20)
    with World(intersection_map, scenario, renderer="gl") as other:
        elsewhere = _front(other, 20)
    for image in (again, elsewhere):
        assert np.array_equal(image.rgb, first.rgb)
        assert np.array_equal(image.depth_m, first.depth_m)
        assert np.array_equal(image.segmentation, first.segmentation)


def test_views_read_through_pixel_buffers_are_the_views_read_at_once(site):
    """On a GPU the renderer queues reads into pixel buffers (`gl_readback`), so that a caller
    draws its next view before it takes this one's pixels. Forced here on llvmpipe: three views
    drawn into the same framebuffer before any is read (the LiDAR's way), then taken in turn,
    and a fourth through the buffers they freed, are byte for byte the views read at once."""
    intersection_map, scenario = site
    with World(intersection_map, scenario, renderer="gl") as world:
        eye = _eye_at(world, 20)

        def toward(yaw: float, segmentation: bool, look: str = "camera"):
            target = eye + 10 * np.array([np.cos(yaw), np.sin(yaw), 0.0])
            return world.render_later(eye, target, 320, 180, 40.0, segmentation=segmentation,
                                      near_m=0.5, look=look)  # fmt: skip

        views = [(0.0, True, "camera"), (2.0, False, "camera"), (4.0, True, "labels")]
        at_once = [toward(*view)() for view in views]
        assert not world.gl.readback.queued  # llvmpipe reads at once by itself
        world.gl.readback = gl_renderer.PixelReads(world.gl.context, queued=True)
        target = eye + 10 * np.array([1.0, 0.0, 0.0])
        world.render(eye, target, 320, 180, 40.0, near_m=0.5)
        assert world.gl.readback.free == {}  # `render` reads at once even so
        pending = [toward(*view) for view in views]
        queued = [taking() for taking in pending]
        queued.append(toward(*views[0])())  # the first view's buffers again
        at_once.append(at_once[0])
        toward(*views[1])  # drawn, never taken: its buffers go with the world
        # three views in flight at once, 3 + 2 + 2 reads; the later two reused freed buffers
        assert len(world.gl.readback.made) == 7
    assert world.gl.readback.made == []  # released with the world
    for ours, expected in zip(queued, at_once, strict=True):
        assert np.array_equal(ours.rgb, expected.rgb)
        assert np.array_equal(ours.depth_m, expected.depth_m)
        if expected.segmentation is None:
            assert ours.segmentation is None
        else:
            assert np.array_equal(ours.segmentation, expected.segmentation)
    assert not np.array_equal(queued[0].rgb, queued[1].rgb)  # three different views
    assert not np.array_equal(queued[0].depth_m, queued[2].depth_m)
    assert queued[2].rgb.max() == 0  # a labels view draws no colour


def test_depth_gathered_at_chosen_pixels_is_the_whole_depth_there(site):
    """On a GPU a camera's depth is read at the pixels box visibility asks for alone (a gather
    pass, `DepthGather`). Forced here on llvmpipe: the samples are the whole image's floats at
    those pixels, in their order, the colour is the same, the whole depth is not read, an empty
    set reads nothing, and a larger set after a smaller grows the buffers."""
    intersection_map, scenario = site
    with World(intersection_map, scenario, renderer="gl") as world:
        eye = _eye_at(world, 20)
        target = eye + 10 * np.array([1.0, 0.0, 0.0])
        whole = world.render(eye, target, 320, 180, 40.0, near_m=0.5)
        assert not world.gl.gathers  # llvmpipe reads the whole image by itself
        world.gl.gathers = True
        rng = np.random.default_rng(2)
        for count in (50, 0, 9000):
            texels = np.stack([rng.integers(0, 320, count), rng.integers(0, 180, count)], 1)
            texels = texels.astype(np.int32)
            image = world.render(eye, target, 320, 180, 40.0, near_m=0.5, depth_at=texels)
            assert image.depth_m is None and image.depth_samples.shape == (count,)
            assert image.depth_samples.dtype == np.float32
            expected = whole.depth_m[texels[:, 1], texels[:, 0]]
            assert np.array_equal(image.depth_samples, expected), count
            assert np.array_equal(image.rgb, whole.rgb)
        assert world.gl.gather.capacity >= 9000
    assert world.gl.gather is None  # released with the world
    assert len(np.unique(expected)) > 100  # sky, road and buildings: many depths


@pytest.mark.parametrize("on_gpu", [True, False])
def test_reduced_views_are_the_views_drawn_and_area_resized(site, on_gpu):
    """The closed-loop observer's cameras come back area-resized, all drawn before any is read
    (`World.render_reduced`): on a GPU by a shader pass (forced here on llvmpipe), where GL
    draws on the CPU by OpenCV. Each pixel is the byte OpenCV's area resize gives of the whole
    view drawn: the same bytes on the CPU, and on the GPU by a whole factor (halves rounded
    up, as OpenCV does there); by 3.125 (800x450 to 256x144, TCP's) within a level on under 1%
    of the pixels. Views smaller than the size asked are enlarged by OpenCV's area resize, as
    the Dataset enlarges a small logged image."""
    import cv2

    intersection_map, scenario = site
    with World(intersection_map, scenario, renderer="gl") as world:
        world.gl.reduces = on_gpu
        eye = _eye_at(world, 20)
        # (drawn, size, most levels off and share of pixels off on the GPU): by 3.125, weighted
        # sums in another order than OpenCV's may round the other way
        cases = (((288, 162), (96, 54), 0, 0.0), ((192, 108), (96, 54), 0, 0.0),
                 ((800, 450), (256, 144), 1, 0.01))  # fmt: skip
        targets = [eye + 10 * np.array([np.cos(yaw), np.sin(yaw), 0.0]) for yaw in (0, 2, 4)]
        for drawn, size, tolerance, share in cases:
            wholes = [world.render(eye, target, *drawn, 40.0, near_m=0.5) for target in targets]
            views = [(eye, target, *drawn, 40.0) for target in targets]
            reduced = world.render_reduced(views, size, near_m=0.5)
            for whole, rgb in zip(wholes, reduced, strict=True):
                expected = cv2.resize(np.ascontiguousarray(whole.rgb), size,
                                      interpolation=cv2.INTER_AREA)  # fmt: skip
                assert rgb.shape == (size[1], size[0], 3)
                difference = np.abs(rgb.astype(int) - expected.astype(int))
                assert difference.max() <= (tolerance if on_gpu else 0), drawn
                assert (difference > 0).mean() <= share, drawn
                assert len(np.unique(expected.reshape(-1, 3), axis=0)) > 200  # not a blank
        whole = world.render(eye, targets[0], 96, 54, 40.0, near_m=0.5)
        (enlarged,) = world.render_reduced([(eye, targets[0], 96, 54, 40.0)], (128, 72),
                                           near_m=0.5)  # fmt: skip
        expected = cv2.resize(np.ascontiguousarray(whole.rgb), (128, 72),
                              interpolation=cv2.INTER_AREA)  # fmt: skip
        assert np.array_equal(enlarged, expected)


@pytest.mark.parametrize("on_gpu", [True, False])
def test_night_noise_added_by_the_reduction_is_the_noise_averaged_on_the_cpu(site, on_gpu):
    """A night camera's noise, made at its full size (1600x900) and averaged over each reduced
    pixel, is added by the reduction itself (on a GPU its shader reads the pool: forced here on
    llvmpipe): the same bytes as `conditions.with_reduced_noise` on the reduced view, at TCP's
    input (800x450 drawn, 256x144) and the camera policy's (400x225, 128x72), a view without
    a start left as drawn, and starts near the pool's end read."""
    from drivee2e_data.sim.conditions import NOISE_POOL_VALUES, with_reduced_noise

    intersection_map, scenario = site
    full_size, full_shape = (1600, 900), (900, 1600)
    last_start = NOISE_POOL_VALUES - 1600 * 900 * 3
    with World(intersection_map, scenario, renderer="gl") as world:
        world.gl.reduces = on_gpu
        eye = _eye_at(world, 20)
        targets = [eye + 10 * np.array([np.cos(yaw), np.sin(yaw), 0.0]) for yaw in (0, 2, 4)]
        for drawn, size in (((800, 450), (256, 144)), ((400, 225), (128, 72))):
            views = [(eye, target, *drawn, 40.0) for target in targets]
            plain = world.render_reduced(views, size, near_m=0.5)
            starts = [12345, None, last_start]
            noisy = world.render_reduced(views, size, near_m=0.5, noise_starts=starts,
                                         full_size=full_size)  # fmt: skip
            for rgb, got, start in zip(plain, noisy, starts, strict=True):
                expected = rgb if start is None else with_reduced_noise(rgb, start, full_shape)
                assert np.array_equal(got, expected), (drawn, start)
            assert not np.array_equal(noisy[0], plain[0])
        with pytest.raises(ValueError, match="full size"):
            world.render_reduced(views, size, near_m=0.5, noise_starts=starts)


def test_showing_the_ego_between_two_draws_of_a_frame_changes_only_the_ego(site):
    """Collection syncs each frame twice (the cameras with the ego hidden, the top view with it
    shown); the actors whose pose did not change keep their placed vertices. The ego's body
    shows in the second draw, and hiding it again gives the first image back."""
    intersection_map, scenario = site
    ego = scenario.ego
    with World(intersection_map, scenario, renderer="gl") as world:
        hidden = _front(world, 20)
        world.place_ego(float(ego.x_m[20]), float(ego.y_m[20]), None)  # shown
        world.set_time(20)
        eye = np.array([ego.x_m[20], ego.y_m[20], 30.0])  # from above, as the top view
        above = world.render(eye, eye - np.array([0, 0, 1.0]), 160, 160, 40.0,
                             segmentation=True, near_m=0.5, up=(1.0, 0.0, 0.0))  # fmt: skip
        again = _front(world, 20)
    ego_body = world.bodies[ego.track_id]
    assert (above.segmentation == ego_body).sum() > 50  # the ego seen from above
    assert not (hidden.segmentation == ego_body).any()
    assert np.array_equal(again.rgb, hidden.rgb)
    assert np.array_equal(again.segmentation, hidden.segmentation)


def test_the_clips_lighting_shades_the_gl_world(site):
    """The world's `ShaderLook` reaches the image: a low, warm sun from another side changes
    it, and the clip's own look brings the first image back."""
    intersection_map, scenario = site
    with World(intersection_map, scenario, renderer="gl") as world:
        first = _front(world, 0, segmentation=False).rgb
        warm_sun = replace(world.look, light_direction=(0.0, -0.97, 0.26), sun_rgb=(0.9, 0.7, 0.5))
        world.gl.set_look(warm_sun)
        warm = _front(world, 0, segmentation=False).rgb
        world.gl.set_look(world.look)
        again = _front(world, 0, segmentation=False).rgb
    assert np.array_equal(again, first)
    difference = warm.astype(int) - first.astype(int)
    assert np.abs(difference).mean() > 2.0
    assert difference[..., 2].mean() < difference[..., 0].mean()  # less blue than red


def _low_sun_behind(world: World, frame: int) -> ShaderLook:
    """The clip's look with shadows on and the sun 15 degrees up behind the ego at `frame`
    (its shadow falls ahead, into the front camera's view)."""
    yaw = float(world.scenario.ego.yaw_rad[frame])
    elevation = np.radians(15.0)
    towards_sun = (-np.cos(yaw) * np.cos(elevation), -np.sin(yaw) * np.cos(elevation),
                   np.sin(elevation))  # fmt: skip
    return replace(world.look, light_direction=tuple(float(v) for v in towards_sun),
                   sun_rgb=(0.9, 0.9, 0.9), shadows=True)  # fmt: skip


def test_a_frames_cameras_and_top_view_share_one_shadow_map(site, monkeypatch):
    """The cameras (the ego hidden but casting its shadow) and the top view (the ego shown) of
    a frame cast the same shadows: one shadow pass for both, and the top view is the image a
    shadow map drawn afresh for it gives."""
    intersection_map, scenario = site
    ego = scenario.ego
    passes = []
    original = GLRenderer._shadow_pass
    monkeypatch.setattr(GLRenderer, "_shadow_pass",
                        lambda self, matrix: (passes.append(1), original(self, matrix)))  # fmt: skip
    with World(intersection_map, scenario, renderer="gl") as world:
        world.gl.set_look(_low_sun_behind(world, 20))
        _front(world, 20, segmentation=False)
        assert len(passes) == 1
        world.place_ego(float(ego.x_m[20]), float(ego.y_m[20]), None)  # shown
        world.set_time(20)
        eye = np.array([ego.x_m[20], ego.y_m[20], 30.0])

        def above():  # type: ignore[no-untyped-def]
            return world.render(eye, eye - np.array([0, 0, 1.0]), 160, 160, 40.0, near_m=0.5,
                                up=(1.0, 0.0, 0.0), look="plain").rgb  # fmt: skip

        shared = above()
        assert len(passes) == 1  # the cameras' map
        world.gl.shadowed = None
        fresh = above()
        assert len(passes) == 2
    assert np.array_equal(shared, fresh)


def test_the_top_view_of_the_cameras_state_draws_the_ego_as_a_view_with_it_shown(site):
    """`casters_drawn`: the ego, hidden from its cameras and casting its shadow, drawn where it
    stands, gives the image of a state with the ego shown, without syncing the bodies again;
    without it the ego is missing."""
    intersection_map, scenario = site
    ego = scenario.ego
    with World(intersection_map, scenario, renderer="gl") as world:
        world.gl.set_look(_low_sun_behind(world, 20))
        _front(world, 20, segmentation=False)  # the cameras' state
        synced = world.gl.synced
        eye = np.array([ego.x_m[20], ego.y_m[20], 30.0])

        def above(casters_drawn: bool):  # type: ignore[no-untyped-def]
            return world.render(eye, eye - np.array([0, 0, 1.0]), 160, 160, 40.0, near_m=0.5,
                                up=(1.0, 0.0, 0.0), look="plain",
                                casters_drawn=casters_drawn).rgb  # fmt: skip

        drawn, missing = above(True), above(False)
        assert world.gl.synced == synced  # no second sync
        world.place_ego(float(ego.x_m[20]), float(ego.y_m[20]), None)  # shown
        world.set_time(20)
        shown = above(False)
    assert np.array_equal(drawn, shown)
    # the ego covers the middle of the view (it stands under the eye)
    assert np.abs(shown[70:90, 70:90].astype(int) - missing[70:90, 70:90]).max() > 30


def shadow_map(world: World) -> bytes:
    """The sun's shadow map as the GL world holds it (read with its context current: another
    library's may be current between draws)."""
    with gl_context.current(world.gl.context):
        return world.gl.shadow_texture.read()


def test_the_shadow_map_from_the_static_casters_copy_is_the_one_drawn_afresh(site, monkeypatch):
    """The static casters are drawn once for a sun matrix (the focus rounded to its grid) and
    copied each frame before the moving casters: after the traffic moved, the map is the one a
    pass drawing every caster into a cleared map gives, and differs from the frame before."""
    if gl_context.depth_copy() is None:
        pytest.skip("no glBlitFramebuffer through EGL here")
    intersection_map, scenario = site
    cast = []
    original = GLRenderer._cast
    monkeypatch.setattr(GLRenderer, "_cast", lambda self, framebuffer, matrix, buffers, clear=True:
                        (cast.append(buffers), original(self, framebuffer, matrix, buffers, clear)))  # fmt: skip
    with World(intersection_map, scenario, renderer="gl") as world:
        world.gl.set_look(_low_sun_behind(world, 20))
        _front(world, 20, segmentation=False)
        before = shadow_map(world)
        _front(world, 21, segmentation=False)  # the ego moved 1 m or less: the same grid point
        copied = shadow_map(world)
        assert cast == [("static",), ("dynamic",), ("dynamic",)]
        monkeypatch.setattr(gl_context, "depth_copy", lambda: None)
        world.gl.shadowed = None
        _front(world, 21, segmentation=False)
        afresh = shadow_map(world)
        assert cast[-1] == ("dynamic", "static")
    assert copied == afresh
    assert copied != before


def test_the_ego_casts_its_shadow_into_its_own_front_camera(site):
    """With the sun low behind the ego, its front camera sees the ego's shadow on the road
    ahead: pixels of the lower half darker than the same frame without the ego casting, and no
    pixel brighter."""
    intersection_map, scenario = site
    with World(intersection_map, scenario, renderer="gl") as world:
        world.gl.set_look(_low_sun_behind(world, 20))
        with_shadow = _front(world, 20, segmentation=False).rgb.astype(int)
        world.scene_lights = replace(world.scene_lights, casters=(), shadow_key=None)
        world.state += 1
        eye = np.array([scenario.ego.x_m[20], scenario.ego.y_m[20], 1.6])
        yaw = scenario.ego.yaw_rad[20]
        target = eye + 10 * np.array([np.cos(yaw), np.sin(yaw), 0.0])
        without = world.render(eye, target, 320, 180, 40.0, near_m=0.5).rgb.astype(int)
    darker = with_shadow.sum(axis=2) < without.sum(axis=2) - 6
    assert darker[90:].sum() > 200 and darker[:90].sum() == 0
    assert not (with_shadow.sum(axis=2) > without.sum(axis=2) + 3).any()
