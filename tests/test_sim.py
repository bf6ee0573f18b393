"""The pybullet twin and replay: known answers on a small synthetic scene."""

import os
import subprocess
import sys
from collections import Counter
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest

from drivee2e_data import pipeline, store
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.scenario import SignalState
from drivee2e_data.sim import twin as twin_module
from drivee2e_data.sim import twin_plan
from drivee2e_data.sim.actors import geometry_key
from drivee2e_data.sim.twin_plan import CROWN_RGBAS, FACADE_RGBAS
from drivee2e_data.sim.world import World, connect, tracks_shown_in
from tests.factories import egl_world, front_view, synthetic_clip


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    return synthetic_clip(tmp_path_factory.mktemp("sim"))


@pytest.fixture(scope="module")
def world(clip):
    intersection_map, scenario = clip
    with World(intersection_map, scenario, renderer="tiny", draw_radius_m=1e6) as replay:
        yield replay


def test_actor_appears_at_its_logged_pose_to_1mm(world, clip):
    _, scenario = clip
    frame = scenario.num_frames // 2
    world.set_time(frame)
    checked = 0
    for track in scenario.tracks:
        if not track.valid[frame]:
            continue
        position, yaw = world.actor_pose(track.track_id)
        assert np.hypot(position[0] - track.x_m[frame], position[1] - track.y_m[frame]) < 1e-3
        assert abs(np.angle(np.exp(1j * (yaw - track.yaw_rad[frame])))) < 1e-3
        checked += 1
    assert checked > 10


def test_invalid_agents_are_hidden(world, clip):
    _, scenario = clip
    track = next(t for t in scenario.tracks if not t.valid.all())
    frame = int(np.flatnonzero(~track.valid)[0])
    world.set_time(frame)
    assert world.actor_pose(track.track_id)[0][2] < -50


def test_a_world_for_some_frames_models_only_the_actors_in_them(world, clip):
    """A collection unit's world: models for the tracks valid in its frames (and the ego), a
    body for every track in the same order (so the ids match a whole clip's world), and a
    clear error if asked to show a frame where an unmodelled track appears."""
    intersection_map, scenario = clip
    frames = range(0, 10)
    expected = tracks_shown_in(scenario, frames)
    valid_early = {t.track_id for t in scenario.tracks if t.valid[:10].any()}
    assert expected == valid_early | {scenario.ego.track_id}
    assert len(expected) < len(scenario.tracks)  # some tracks appear later
    assert tracks_shown_in(scenario, None) == {t.track_id for t in scenario.tracks}
    with World(intersection_map, scenario, renderer="tiny", draw_radius_m=1e6,
               frames=frames) as part:  # fmt: skip
        assert set(part.models) == expected
        assert part.bodies == world.bodies
        part.set_time(9)
        late = next(t for t in scenario.tracks if t.track_id not in expected and t.valid.any())
        with pytest.raises(DriveE2EError, match=f"track {late.track_id!r} shows"):
            part.set_time(int(np.flatnonzero(late.valid)[0]))


def _look_at_head(world, intersection_map, signal_id):
    head = next(h for h in intersection_map.signal_heads if h.signal_id == signal_id)
    facing = np.array([np.cos(head.facing_yaw_rad), np.sin(head.facing_yaw_rad), 0.0])
    target = head.position_m + np.array([0.0, 0.0, 0.5])
    return world.render(target + 4.0 * facing, target, 96, 96, 30.0).rgb


@pytest.mark.parametrize("state", [SignalState.RED, SignalState.GREEN])
def test_a_signal_logged_in_a_state_shows_that_colour(world, clip, state):
    intersection_map, scenario = clip
    signal = next(
        s for s in scenario.signals if s.signal_id.startswith("sig_") and (s.states == state).any()
    )
    world.set_time(int(np.flatnonzero(signal.states == state)[0]))
    rgb = _look_at_head(world, intersection_map, signal.signal_id).astype(int)
    red = (rgb[:, :, 0] > 180) & (rgb[:, :, 1] < 80)
    green = (rgb[:, :, 1] > 180) & (rgb[:, :, 0] < 80)
    lit, dark = (red, green) if state == SignalState.RED else (green, red)
    assert lit.sum() > 20 and dark.sum() == 0


def test_same_frame_renders_identical_pixels(world, clip):
    _, scenario = clip
    ego = scenario.ego
    world.place_ego(ego.x_m[10], ego.y_m[10], ego.track_id)
    world.set_time(10)
    eye = np.array([ego.x_m[10], ego.y_m[10], 1.6])
    target = eye + 10 * np.array([np.cos(ego.yaw_rad[10]), np.sin(ego.yaw_rad[10]), 0.0])
    first = world.render(eye, target, 160, 90, 40.0)
    world.set_time(40)
    world.set_time(10)
    second = world.render(eye, target, 160, 90, 40.0)
    assert np.array_equal(first.rgb, second.rgb) and np.array_equal(first.depth_m, second.depth_m)
    assert first.rgb.std() > 10  # a scene, not a blank frame


def test_depth_is_metric(world):
    world.set_time(0)
    image = world.render(np.array([0.0, 0.0, 30.0]), np.array([0.0, 0.001, 0.0]), 64, 64, 10.0)
    centre = image.depth_m[32, 32]
    assert 29.9 < centre < 30.1  # the road surface straight below the camera


def test_unknown_renderer_is_a_clear_error():
    with pytest.raises(DriveE2EError, match="renderer 'vulkan'"):
        connect("vulkan")


def test_auto_renderer_falls_back_cleanly():
    import pybullet

    client, chosen = connect("auto")
    assert chosen in ("gl", "egl", "tiny")
    pybullet.disconnect(client)


def test_concave_polygon_triangulates_exactly():
    import shapely

    l_shape = shapely.Polygon([(0, 0), (4, 0), (4, 1), (1, 1), (1, 3), (0, 3)])
    vertices, indices = twin_plan.triangulate(l_shape)
    area = sum(
        abs(twin_plan._signed_area(vertices[indices[k : k + 3]])) for k in range(0, len(indices), 3)
    )
    assert area == pytest.approx(l_shape.area)


def _outward_triangles(vertices, indices, centre) -> tuple[int, int]:
    """(triangles, triangles whose right-hand normal points away from `centre`)."""
    triangles = vertices[np.asarray(indices).reshape(-1, 3)]
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    outward = ((triangles.mean(axis=1) - centre) * normals).sum(axis=1) > 0
    return len(triangles), int(outward.sum())


def test_twin_meshes_wind_outward_and_close():
    centre = np.array([1.0, 2.0, 3.0])
    vertices, indices = twin_plan.box_mesh(centre, 0.7, np.array([4.0, 2.0, 1.5]))
    assert _outward_triangles(vertices, indices, centre) == (12, 12)
    assert np.allclose(np.sort(np.abs((vertices - centre)[:, 2])), 0.75)
    vertices, indices, normals = twin_plan.sphere_mesh(centre, 2.0, rings=8, segments=12)
    assert _outward_triangles(vertices, indices, centre) == (2 * 12 * 7, 2 * 12 * 7)
    assert np.allclose(np.linalg.norm(vertices - centre, axis=1), 2.0)
    assert np.allclose(normals, (vertices - centre) / 2.0)
    clockwise = np.array([[0.0, 0.0], [0.0, 4.0], [5.0, 4.0], [5.0, 0.0]])
    vertices, indices = twin_plan.prism_mesh(clockwise, 0.0, 3.0)
    # four walls of two triangles and a roof of two
    assert _outward_triangles(vertices, indices, np.array([2.5, 2.0, 1.5])) == (10, 10)


def test_twin_draws_one_body_per_kind_and_colour_and_one_per_lamp(clip):
    """Static elements merge (pybullet's renderer pays per body drawn); lamps stay apart, as
    `Twin.show` colours each one."""
    intersection_map, scenario = clip
    with World(intersection_map, scenario, renderer="tiny") as replay:
        twin = replay.twin
        lamps = {body for lamps in twin.lamps.values() for body, _ in lamps}
        assert len(lamps) == 3 * len(intersection_map.signal_heads) > 0
        merged = [body for body in twin.bodies if body not in lamps]
        colours = {
            body: tuple(np.round(replay.p.getVisualShapeData(body, physicsClientId=replay.client)[0][7], 3))
            for body in merged
        }  # fmt: skip
        pairs = [(twin.segmentation[body], colours[body]) for body in merged]
        assert len(pairs) == len(set(pairs))
        counts = Counter(kind for kind, _ in pairs)
        assert counts["road"] == counts["ground"] == 1
        assert 1 <= counts["building"] <= len(FACADE_RGBAS)  # facades in a few colours
        # trunks and crowns in a few greens
        assert (2 <= counts["vegetation"] <= 1 + len(CROWN_RGBAS)) == bool(intersection_map.trees)
        assert counts["crosswalk"] == (2 if intersection_map.crosswalks else 0)


def test_world_builds_on_real_map(tmp_path: Path):
    from conftest import REALDATA

    if not REALDATA.is_dir():
        pytest.skip("../shared/realdata is absent")
    from drivee2e_data.sources import commonroad

    imported = commonroad.import_commonroad(REALDATA / "commonroad" / "USA_Peach-4_8_T-1.xml")
    with World(imported.intersection_map, imported.scenario, renderer="tiny") as replay:
        replay.set_time(0)
        assert len(replay.twin.lamps) == 4


def test_a_labels_outline_lies_around_its_text_along_the_whole_line():
    from drivee2e_data.sensors.contact_sheet import outlined_text

    caption = "synth_s0_c0013  frame 20  renderer gl"
    image = np.full((40, 480, 3), 128, np.uint8)
    outlined_text(image, caption, (8, 26))
    bright = np.argwhere(image[..., 0] > 160)  # on a background of 128
    dark = np.argwhere(image[..., 0] < 96)
    # the dark pixels are the white glyphs' one-pixel border: their extent is the text's, a
    # pixel wider each way (a thick dark pass under a thin white one ended 21 pixels past it)
    assert len(bright) > 500 and len(dark) > 500
    assert (dark.min(axis=0) - bright.min(axis=0)).tolist() == [-1, -1]
    assert (dark.max(axis=0) - bright.max(axis=0)).tolist() == [1, 1]


def test_view_cli_writes_a_contact_sheet(tmp_path: Path, capsys):
    import cv2

    from drivee2e_data.cli import main

    pipeline.synthesize(tmp_path, clips=1, seed=3)
    scenario_id = store.scenario_ids(tmp_path)[0]
    out = tmp_path / "sheet.png"
    assert (
        main(
            [
                "view",
                str(tmp_path),
                scenario_id,
                "--frame",
                "5",
                "--out",
                str(out),
                "--renderer",
                "tiny",
            ]
        )
        == 0
    )
    sheet = cv2.imread(str(out))
    assert sheet.shape == (540, 3 * 480 + 540, 3) and sheet.std() > 20
    assert main(["view", str(tmp_path), scenario_id, "--frame", "99999", "--out", str(out)]) == 2
    assert "frame 99999 is outside" in capsys.readouterr().err


def test_sun_position_known_answers():
    from datetime import datetime, timezone

    from drivee2e_data.hdmap import GeoOrigin
    from drivee2e_data.sun import sun_position

    beijing = GeoOrigin(39.9, 116.4)
    azimuth, elevation = sun_position(datetime(2026, 6, 21, 4, 16, tzinfo=timezone.utc), beijing)
    assert np.rad2deg(elevation) == pytest.approx(
        90 - 39.9 + 23.44, abs=1.5
    )  # local solar noon (116.4 E: 04:16 UTC)
    assert np.rad2deg(azimuth) == pytest.approx(180.0, abs=5.0)  # due south
    assert (
        sun_position(datetime(2026, 6, 21, 16, 0, tzinfo=timezone.utc), beijing)[1] < 0
    )  # midnight
    morning_azimuth = sun_position(datetime(2026, 3, 20, 0, 30, tzinfo=timezone.utc), beijing)[0]
    assert 60 < np.rad2deg(morning_azimuth) < 120  # the sun rises in the east


def test_weather_and_night_post_processing():
    from datetime import datetime, timezone

    from drivee2e_data.scenario import Conditions, TimeOfDay, Weather
    from drivee2e_data.sim.conditions import Lighting, post_process

    rgb = np.full((40, 40, 3), 60, np.uint8)
    depth = np.tile(np.linspace(2.0, 300.0, 40, dtype=np.float32)[:, None], (1, 40))
    day = Lighting((0, 0, 1), (1, 1, 1), 0.5, 0.5, False)
    night = Lighting((0, 0, 1), (1, 1, 1), 0.5, 0.5, True)
    when = datetime(2026, 5, 1, tzinfo=timezone.utc)
    fog = post_process(rgb, depth, Conditions(Weather.FOG, TimeOfDay.NOON, when), day, seed=1)
    assert fog[0].mean() < 80 and fog[-1].mean() > 190  # near stays dark, far goes to fog
    dark = post_process(rgb, depth, Conditions(Weather.CLEAR, TimeOfDay.NIGHT, when), night, seed=1)
    assert dark.mean() < 25
    again = post_process(
        rgb, depth, Conditions(Weather.CLEAR, TimeOfDay.NIGHT, when), night, seed=1
    )
    assert np.array_equal(dark, again)
    rain = post_process(rgb, depth, Conditions(Weather.RAIN, TimeOfDay.NOON, when), day, seed=2)
    assert rain.max() > 100  # streaks


def test_generated_buildings_keep_off_the_road_and_repeat():
    import shapely
    from factories import small_map

    from drivee2e_data.hdmap import StopLine
    from drivee2e_data.sim.scenery import BUILDING_SETBACK_M, generated_buildings

    bare = small_map(stop_lines=(StopLine("s", np.array([[50.0, 1.75], [50.0, -1.75]]), ("l1",)),))
    first, second = generated_buildings(bare), generated_buildings(bare)
    assert first and all(b.generated for b in first)
    assert [b.footprint_m.tolist() for b in first] == [b.footprint_m.tolist() for b in second]
    road = bare.drivable_union()
    for building in first:
        assert shapely.Polygon(building.footprint_m).distance(road) >= BUILDING_SETBACK_M - 1e-6


@pytest.mark.slow
def test_one_twin_serves_all_clips_of_its_map(tmp_path: Path):
    pipeline.synthesize(tmp_path, clips=3, seed=5, intersections=1)
    scenarios = [store.read_scenario(tmp_path, i) for i in store.scenario_ids(tmp_path)]
    intersection_map = store.read_map(tmp_path, scenarios[0].map_id)
    with World(intersection_map, scenarios[0], renderer="tiny", draw_radius_m=1e6) as world:
        twin_bodies = list(world.twin.bodies)
        for scenario in scenarios[1:]:
            world.replay(scenario)
            world.set_time(5)
            track = next(t for t in scenario.tracks if t.valid[5])
            position, _ = world.actor_pose(track.track_id)
            assert np.hypot(position[0] - track.x_m[5], position[1] - track.y_m[5]) < 1e-3
        assert world.twin.bodies == twin_bodies
        other = type(scenarios[0])(**{**scenarios[0].__dict__, "map_id": "elsewhere"})
        with pytest.raises(DriveE2EError, match="is on map 'elsewhere'"):
            world.replay(other)


@pytest.mark.slow
def test_vehicles_of_one_blueprint_share_a_collision_shape_that_outlives_a_replay(tmp_path: Path):
    """One collision shape per model geometry in a world: the cars of a blueprint share one, a
    replay's bodies take the shapes made before, and rays hit each body where it stands."""
    import pybullet

    pipeline.synthesize(tmp_path, clips=2, seed=5, intersections=1)
    first, second = (store.read_scenario(tmp_path, i) for i in store.scenario_ids(tmp_path))
    intersection_map = store.read_map(tmp_path, first.map_id)
    with World(intersection_map, first, renderer="tiny", draw_radius_m=1e6) as world:
        made = []
        for scenario in (first, second):
            if scenario is second:
                world.replay(second)
            cars = [t for t in scenario.tracks if world.blueprints[t.track_id].name == "sedan"]
            assert len(cars) >= 2
            (key,) = {
                geometry_key(world.models[t.track_id]) for t in cars if t.track_id in world.models
            }
            made.append(world.collision_shapes[key])
            geometries = {geometry_key(model) for model in world.models.values()}
            assert geometries <= set(world.collision_shapes)
            assert len(world.collision_shapes) < len(world.bodies)
            frame = next(f for f in range(scenario.num_frames) if cars[0].valid[f])
            world.set_time(frame)
            x, y, z = (cars[0].x_m[frame], cars[0].y_m[frame], 10.0)
            hit = pybullet.rayTest([x, y, z], [x, y, -1.0], physicsClientId=world.client)[0]
            assert hit[0] == world.bodies[cars[0].track_id]
        assert made[0] == made[1]  # the second clip's sedans took the first's shape


def test_an_egl_world_superseded_by_a_newer_one_refuses_to_render(clip):
    """pybullet's EGL plugin draws only in the newest client's context: an older world rendering
    after a newer one came and went read back garbage (seen as a collection in a test session
    writing noise); it is now an error, and `world_for` builds a fresh world instead."""
    from drivee2e_data.sim.world import world_for

    intersection_map, scenario = clip
    older = egl_world(intersection_map, scenario)
    try:
        before = front_view(older, 10)
        with World(intersection_map, scenario, renderer="egl"):
            pass
        assert not older.can_render
        with pytest.raises(DriveE2EError, match="superseded"):
            front_view(older, 10)
        fresh = world_for(older, scenario, lambda map_id: intersection_map, "egl")
        assert fresh is not older
        with fresh:
            assert np.array_equal(front_view(fresh, 10).rgb, before.rgb)
    finally:
        older.close()


def test_large_egl_images_are_drawn_at_the_window_size_and_resized(clip):
    """The EGL plugin draws at most 1024x768: a 1600x900 request is drawn at 1024x576 (its
    aspect ratio kept: square pixels) and comes back at 1600x900, its body mask the nearest
    drawn pixel's (the native drawing, resized by index)."""
    intersection_map, scenario = clip
    world = egl_world(intersection_map, scenario)
    with world:
        assert world.drawn_size(1600, 900) == (1024, 576)
        assert world.drawn_size(1200, 1200) == (768, 768)
        assert world.drawn_size(320, 180) == (320, 180)
        full = front_view(world, 10, (1600, 900), segmentation=True)
        native = front_view(world, 10, (1600, 900), segmentation=True, native=True)
    assert full.rgb.shape == (900, 1600, 3) and native.rgb.shape == (576, 1024, 3)
    rows = ((np.arange(900) + 0.5) * 576 / 900).astype(int)
    columns = ((np.arange(1600) + 0.5) * 1024 / 1600).astype(int)
    assert np.array_equal(full.segmentation, native.segmentation[rows[:, None], columns])
    assert np.array_equal(full.depth_m, native.depth_m[rows[:, None], columns])
    assert np.abs(full.rgb.astype(int).mean((0, 1)) - native.rgb.mean((0, 1))).max() < 2.0


def test_sensor_noise_is_seeded_whole_levels_of_sigma_six_and_differs_between_seeds():
    from drivee2e_data.sim.conditions import NIGHT_NOISE_SIGMA, noise_pool, sensor_noise

    first = sensor_noise((768, 1024, 3), np.random.default_rng(7))
    again = sensor_noise((768, 1024, 3), np.random.default_rng(7))
    other = sensor_noise((768, 1024, 3), np.random.default_rng(8))
    assert np.array_equal(first, again) and not np.array_equal(first, other)
    assert first.dtype == np.int8
    assert abs(first.mean()) < 0.05 and abs(first.std() - NIGHT_NOISE_SIGMA) < 0.05
    full = sensor_noise((900, 1600, 3), np.random.default_rng(7))  # a camera: from the pool
    assert np.shares_memory(full, noise_pool())
    big = sensor_noise((2000, 2000, 3), np.random.default_rng(7))  # beyond half the pool
    assert big.shape == (2000, 2000, 3) and abs(big.std() - NIGHT_NOISE_SIGMA) < 0.05
    assert not np.shares_memory(big, noise_pool())


@pytest.mark.parametrize("shape", [(900, 1600, 3), (2000, 2000, 3)])  # from the pool; afresh
def test_noise_added_as_its_rises_and_falls_is_the_saturating_add_of_its_levels(shape):
    """`with_sensor_noise` adds the pool's rises, then takes away its falls (two uint8 passes):
    the same bytes as adding the int8 levels with saturation, the input left as it was."""
    import cv2

    from drivee2e_data.sim.conditions import sensor_noise, with_sensor_noise

    image = np.random.default_rng(3).integers(0, 256, shape, dtype=np.uint8)
    image[0, :50] = 0  # saturates below and above
    image[1, :50] = 255
    before = image.copy()
    noisy = with_sensor_noise(image, np.random.default_rng(5))
    expected = cv2.add(image, sensor_noise(shape, np.random.default_rng(5)), dtype=cv2.CV_8U)
    assert np.array_equal(noisy, expected)
    assert np.array_equal(image, before)
    assert (noisy[0, :50] < 20).all() and (noisy[1, :50] > 235).all()


def test_night_noise_on_a_shaded_image_is_a_saturating_add_of_the_levels():
    from drivee2e_data.scenario import Conditions, TimeOfDay, Weather
    from drivee2e_data.sim.conditions import Lighting, post_process, sensor_noise

    rgb = np.random.default_rng(1).integers(0, 256, (90, 160, 3), dtype=np.uint8)
    rgb[0, :10] = 0  # dark and bright pixels: the noise saturates instead of wrapping
    rgb[1, :10] = 255
    night = Lighting((0.0, 0.0, 1.0), (1.0, 0.85, 0.6), 0.5, 0.4, True)
    conditions = Conditions(
        Weather.CLEAR, TimeOfDay.NIGHT, datetime(2026, 5, 1, tzinfo=timezone.utc)
    )
    image = post_process(rgb, np.ones((90, 160), np.float32), conditions, night, 11, shaded=True)
    noise = sensor_noise(rgb.shape, np.random.default_rng(11))
    assert np.array_equal(image, np.clip(rgb.astype(int) + noise, 0, 255))


def test_rain_streaks_blend_as_opencvs_blend_linear_does_at_the_pixels_they_touch():
    import cv2

    from drivee2e_data.sim.conditions import RAIN_RGB, _rain, rain_streaks

    rgb = np.random.default_rng(2).integers(0, 256, (450, 800, 3), dtype=np.uint8)
    for seed in range(4):
        streaks = rain_streaks(rgb.shape[:2], np.random.default_rng(seed))
        expected = cv2.blendLinear(rgb, np.full_like(rgb, RAIN_RGB), 1.0 - streaks, streaks)
        rained = _rain(rgb, np.random.default_rng(seed))
        assert np.array_equal(rained, expected)
        assert 0.005 < (rained != rgb).any(axis=2).mean() < 0.2  # streaks, not the whole image


def test_a_new_twin_folder_clears_those_of_processes_gone(tmp_path: Path):
    """Mesh folders are named for their process; those whose process no longer runs (a worker
    killed before it could clean up) are deleted when the next is made, others are kept."""
    gone = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    dead = tmp_path / f"drivee2e_twin_{int(gone.stdout)}_abc"
    live = tmp_path / f"drivee2e_twin_{os.getpid()}_def"
    unnamed = tmp_path / "drivee2e_twin_ghi"  # an older version's: whose it was is not known
    for folder in (dead, live, unnamed):
        folder.mkdir()
        (folder / "mesh_00000.obj").write_text("v 0 0 0\n")
    made = twin_module.mesh_folder(tmp_path)
    assert made.is_dir() and made.name.startswith(f"drivee2e_twin_{os.getpid()}_")
    assert not dead.exists()
    assert live.is_dir() and unnamed.is_dir()


def test_rgb_views_of_a_bgra_read_are_made_contiguous_by_the_fast_path():
    """The GL renderer's colour is an RGB view of the BGRA read back; the CPU weather (rain's
    streaks, night noise) needs it contiguous: the same bytes as numpy's copy, by OpenCV's
    conversion (numpy's copy of such a view had cost 6 ms a camera), whatever the view."""
    from unittest import mock

    from drivee2e_data.sim import gl_readback

    rng = np.random.default_rng(4)
    bgra = rng.integers(0, 256, (90, 160, 4), dtype=np.uint8)
    rgb = bgra[..., 2::-1]
    with mock.patch.object(np, "ascontiguousarray", side_effect=AssertionError("slow path")):
        made = gl_readback.contiguous_rgb(rgb)
    assert made.flags.c_contiguous and made.base is not bgra
    assert np.array_equal(made, rgb)
    plain = np.ascontiguousarray(rgb)
    assert gl_readback.contiguous_rgb(plain) is plain  # already contiguous: itself
    other = bgra[..., 1:]  # not the first three channels backwards: copied the plain way
    assert np.array_equal(gl_readback.contiguous_rgb(other), other)
    assert gl_readback.contiguous_rgb(other).flags.c_contiguous


def test_shaded_rain_and_night_effects_are_the_same_on_a_bgra_view_and_a_copy():
    from datetime import datetime, timezone

    from drivee2e_data.scenario import Conditions, TimeOfDay, Weather
    from drivee2e_data.sim.conditions import Lighting, post_process

    rng = np.random.default_rng(5)
    rgba = rng.integers(0, 256, (90, 160, 4), dtype=np.uint8)
    depth = np.full((90, 160), 30.0, np.float32)
    night = Lighting((0, 0, 1), (1, 1, 1), 0.5, 0.5, True)
    when = datetime(2026, 5, 1, tzinfo=timezone.utc)
    for weather in (Weather.RAIN, Weather.FOG, Weather.CLEAR):
        conditions = Conditions(weather, TimeOfDay.NIGHT, when)
        for shaded in (True, False):
            view = post_process(rgba[..., 2::-1], depth, conditions, night, 7, shaded=shaded)
            copy = post_process(
                np.ascontiguousarray(rgba[..., 2::-1]), depth, conditions, night, 7, shaded=shaded
            )
            assert np.array_equal(view, copy), (weather, shaded)


def test_rain_streaks_are_the_lines_drawn_one_number_and_one_line_at_a_time():
    """The streaks' numbers drawn in one call and their lines in one `polylines` give the same
    weights, and leave the generator where, as a call per number and a `line` per streak (the
    definition, written out here) do."""
    import cv2

    from drivee2e_data.sim.conditions import RAIN_OPACITY, RAIN_STREAKS, rain_streaks

    for shape, seed in (((900, 1600), 0), ((900, 1600), 11), ((90, 160), 3), ((450, 800), 8)):
        rng = np.random.default_rng(seed)
        expected = np.zeros(shape, np.float32)
        height, width = shape
        for _ in range(RAIN_STREAKS):
            x, y = int(rng.integers(width)), int(rng.integers(height))
            length = int(rng.integers(height // 30, height // 10))
            cv2.line(expected, (x, y), (x + length // 6, y + length), 1.0, 1, cv2.LINE_AA)
        expected *= RAIN_OPACITY
        ours = np.random.default_rng(seed)
        assert np.array_equal(rain_streaks(shape, ours), expected), (shape, seed)
        assert ours.integers(1 << 30) == rng.integers(1 << 30)  # the generator left alike
        assert 0.0 < expected.max() <= RAIN_OPACITY and (expected > 0).mean() < 0.1


def test_the_rain_canvas_is_zero_again_after_each_image_even_a_failed_one():
    from unittest import mock

    from drivee2e_data.sim import conditions

    rgb = np.random.default_rng(6).integers(0, 256, (90, 160, 3), dtype=np.uint8)
    first = conditions._rain(rgb, np.random.default_rng(1))
    assert not conditions._streak_canvas((90, 160)).any()
    assert np.array_equal(conditions._rain(rgb, np.random.default_rng(1)), first)  # no leftovers
    with mock.patch.object(np, "flatnonzero", side_effect=MemoryError), pytest.raises(MemoryError):
        conditions._rain(rgb, np.random.default_rng(2))  # fails after drawing
    assert not conditions._streak_canvas((90, 160)).any()
    assert np.array_equal(conditions._rain(rgb, np.random.default_rng(1)), first)


def test_buildings_stand_farther_out_where_the_roads_leave_no_room_and_the_report_says_so(
    monkeypatch: pytest.MonkeyPatch,
):
    import shapely
    from factories import small_map

    from drivee2e_data.hdmap import StopLine
    from drivee2e_data.sim import scenery

    bare = small_map(stop_lines=(StopLine("s", np.array([[50.0, 1.75], [50.0, -1.75]]), ("l1",)),))
    centre = shapely.Point(*scenery.junction_centre(bare))

    def farthest(buildings: list) -> float:
        return max(shapely.Polygon(b.footprint_m).centroid.distance(centre) for b in buildings)

    near = scenery.generated_buildings(bare)
    assert len(near) >= scenery.MIN_GENERATED_BUILDINGS
    assert farthest(near) <= scenery.BUILDING_REACH_M
    # as if the reach held too little room: the buildings go out to the last reach
    monkeypatch.setattr(scenery, "MIN_GENERATED_BUILDINGS", len(near) + 1)
    far = scenery.generated_buildings(bare)
    assert len(far) > len(near)
    assert scenery.BUILDING_REACH_M < farthest(far) <= scenery.BUILDING_REACHES_M[-1]
    report = scenery.scenery_report(bare)
    assert report.generated_buildings == len(far) and "buildings generated" in report.line()
    # no room at any reach: the report says so
    monkeypatch.setattr(scenery, "BUILDING_REACHES_M", (5.0,))
    assert scenery.scenery_report(bare).generated_buildings == 0
    assert "no room for buildings" in scenery.scenery_report(bare).line()


def test_reduced_effects_with_the_noise_added_already_give_the_same_bytes():
    """The closed-loop observer's reduced cameras get the night's noise from the renderer
    (`noise_added`): the rain's streaks then come from the same generator's draws, and the
    image is the one the effects give with the noise added here; an image whose noise is drawn
    afresh (no start) cannot have had it added."""
    from drivee2e_data.scenario import Conditions, TimeOfDay, Weather
    from drivee2e_data.sim.conditions import (
        Lighting,
        night_noise_start,
        reduced_sensor_effects,
        with_reduced_noise,
    )

    when = datetime(2026, 1, 1, 23, tzinfo=timezone.utc)
    night = Lighting((0, 0, 1), (1, 1, 1), 0.5, 0.5, True)
    rgb = np.random.default_rng(3).integers(0, 256, (144, 256, 3), dtype=np.uint8)
    full = (900, 1600)
    for weather in (Weather.RAIN, Weather.CLEAR):
        conditions = Conditions(weather, TimeOfDay.NIGHT, when)
        here = reduced_sensor_effects(rgb, conditions, night, 21, full)
        noisy = with_reduced_noise(rgb, night_noise_start(21, full), full)
        there = reduced_sensor_effects(noisy, conditions, night, 21, full, noise_added=True)
        assert np.array_equal(here, there), weather
        assert not np.array_equal(here, rgb)
    huge = (4000, 3000)  # 36 M values: more than half the pool, drawn afresh
    assert night_noise_start(21, huge) is None
    with pytest.raises(ValueError, match="afresh"):
        reduced_sensor_effects(rgb, conditions, night, 21, huge, noise_added=True)


def test_the_exposures_mean_is_numpys_mean_to_the_bit():
    """`conditions._mean` (the exposure meter's and its bisection's mean, without numpy's
    dispatch) is numpy's float32 mean to the bit, at the meter's sample counts and others, over
    levels from dark to saturated."""
    from drivee2e_data.sim.conditions import _mean

    rng = np.random.default_rng(5)
    for count in (1, 2, 7, 127, 128, 129, 2880, 4321):
        for scale in (1e-3, 1.0, 90.0, 255.0, 1e6):
            values = (rng.random(count, dtype=np.float32) * np.float32(scale)).astype(np.float32)
            assert _mean(values) == float(values.mean()), (count, scale)
            clipped = np.minimum(values * np.float32(1.7), np.float32(255.0))
            assert _mean(clipped) == float(clipped.mean()), (count, scale)
