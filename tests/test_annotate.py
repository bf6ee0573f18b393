"""Annotations: visibility from the camera mask, points in boxes."""

import numpy as np
import pytest
from factories import small_map, small_scenario, straight_track

from drivee2e_data.hdmap import Building
from drivee2e_data.scenario import AgentClass
from drivee2e_data.sensors.annotate import (
    box_corners_3d,
    image_outline,
    points_in_box,
    polygon_area,
    projected_area,
    visibility_level,
    visible_share,
)
from drivee2e_data.sensors.camera import encode_jpeg, render
from drivee2e_data.sensors.rig import default_rig, pose
from drivee2e_data.sim.world import World

FRAMES = 5


def _parked(track_id: str, x_m: float) -> object:
    return straight_track(
        track_id, FRAMES, AgentClass.CAR, x_m=np.full(FRAMES, x_m), vx_mps=np.zeros(FRAMES)
    )


def _scene(with_building: bool):
    building = Building(
        "wall", np.array([[14.0, -4.0], [16.0, -4.0], [16.0, 4.0], [14.0, 4.0]]), 8.0
    )
    intersection_map = small_map(buildings=(building,) if with_building else ())
    scenario = small_scenario(
        FRAMES, tracks=(_parked("ego", 5.0), _parked("hidden", 25.0)), ego_id="ego"
    )
    return intersection_map, scenario


def _front_view(intersection_map, scenario):
    world = World(intersection_map, scenario, renderer="tiny")
    world.place_ego(5.0, 0.0, "ego")
    world.set_time(0)
    ego_to_world = pose(np.eye(3), np.array([5.0 - 1.4, 0.0, 0.0]))
    frame = render(world, default_rig().camera("CAM_FRONT"), ego_to_world)
    return world, frame, ego_to_world


@pytest.mark.parametrize("with_building", [True, False])
def test_a_box_behind_a_building_is_not_visible(with_building):
    intersection_map, scenario = _scene(with_building)
    world, frame, ego_to_world = _front_view(intersection_map, scenario)
    try:
        track = scenario.track("hidden")
        corners = box_corners_3d(track, 0, world.blueprints["hidden"].size_m)
        share = visible_share(frame, world.bodies["hidden"], corners, ego_to_world)
        assert not projected_area(
            frame, corners, ego_to_world
        ).is_empty  # it is in the image's view
        if with_building:
            assert share == 0.0 and visibility_level(share) == 0
        else:
            assert share > 0.8 and visibility_level(share) == 4
            area = projected_area(frame, corners, ego_to_world)
            assert (frame.mask == world.bodies["hidden"]).sum() > 0.8 * area.area
    finally:
        world.close()


def test_image_outline_is_the_hull_clipped_to_the_image():
    """Known answers: a square half off the image's left side keeps its right half; a triangle
    over a corner keeps the part inside; points in a line or wholly beside the image give
    none. Then random point sets against shapely's hull and intersection."""
    import shapely

    square = np.array([[-10.0, 10.0], [10.0, 10.0], [10.0, 30.0], [-10.0, 30.0], [0.0, 20.0]])
    outline = image_outline(square, 100, 50)
    assert polygon_area(outline) == pytest.approx(200.0)
    assert min(x for x, _ in outline) == 0.0 and max(x for x, _ in outline) == 10.0
    corner = image_outline(np.array([[-20.0, -20.0], [40.0, -20.0], [-20.0, 40.0]]), 100, 50)
    assert polygon_area(corner) == pytest.approx(0.5 * 20.0 * 20.0)  # x + y <= 20 in the image
    assert image_outline(np.array([[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]), 100, 50) is None
    assert image_outline(np.array([[-9.0, 1.0], [-1.0, 1.0], [-5.0, 9.0]]), 100, 50) is None
    rng = np.random.default_rng(7)
    image = shapely.box(0, 0, 1600, 900)
    for _ in range(500):
        points = rng.uniform(-800, 2400, 2) + rng.normal(0, rng.choice([5, 300, 2000]), (8, 2))
        expected = shapely.MultiPoint(points).convex_hull.intersection(image)
        outline = image_outline(points, 1600, 900)
        area = 0.0 if outline is None else polygon_area(outline)
        assert area == pytest.approx(expected.area, rel=1e-9, abs=1e-9)
        if outline is not None:
            assert shapely.Polygon(outline).symmetric_difference(expected).area < 1e-6


def test_visibility_levels_follow_nuscenes_bins():
    assert [visibility_level(v) for v in (0.0, 0.2, 0.4, 0.5, 0.7, 0.95)] == [0, 1, 2, 2, 3, 4]


def test_points_in_a_rotated_box():
    track = straight_track(
        "a", 1, yaw_rad=np.array([np.pi / 4]), x_m=np.array([10.0]), y_m=np.array([5.0])
    )
    corners = box_corners_3d(track, 0)
    inside = np.array(
        [[10.0, 5.0, 0.75], [10.0 + 1.5, 5.0 + 1.5, 0.5]]
    )  # centre; 2.1 m along the heading
    outside = np.array(
        [[10.0 + 1.5, 5.0 - 1.5, 0.5], [10.0, 5.0, 2.0]]
    )  # 2.1 m sideways; above the roof
    assert points_in_box(np.concatenate([inside, outside]), corners) == 2


def test_a_sweeps_returns_are_grouped_by_the_bodies_asked_for():
    """Box point counts take each agent's returns (`suite._returns_by_body`): the indices of
    its returns in sweep order, for the bodies asked for that have any, and nothing else."""
    from drivee2e_data.sensors.suite import _returns_by_body

    hit_body = np.array([3, 1, 7, 3, 2, 7, 0, 3], np.int32)
    grouped = _returns_by_body(hit_body, [7, 3, 9])
    assert set(grouped) == {3, 7}  # 9 has no return; 0, 1 and 2 were not asked for
    assert grouped[3].tolist() == [0, 3, 7] and grouped[7].tolist() == [2, 5]
    assert _returns_by_body(hit_body, []) == {}
    assert _returns_by_body(np.zeros(0, np.int32), [3]) == {}
    assert _returns_by_body(hit_body, [12]) == {}  # an id beyond any the sweep hit


def test_jpeg_round_trip_is_close():
    import cv2

    rgb = np.zeros((90, 160, 3), np.uint8)
    rgb[:, :80] = (200, 40, 40)
    decoded = cv2.imdecode(np.frombuffer(encode_jpeg(rgb, 95), np.uint8), cv2.IMREAD_COLOR)[
        :, :, ::-1
    ]
    assert np.abs(decoded.astype(int) - rgb).mean() < 3


def test_jpeg_of_an_rgb_view_of_a_bgra_image():
    """The GL renderer's views are RGB views of the BGRA it read (its first three bytes
    backwards): encoded from the BGRA as it is, to the same bytes as the contiguous RGB; a
    window of such a read (a view of an atlas of views side by side) is its window of BGRA
    pixels; other views of a four-channel array (RGBA's first three, BGRA's last three, BGRA's
    first three without the flip) are not taken for one."""
    from drivee2e_data.sim.gl_readback import bgra_under

    rng = np.random.default_rng(3)
    bgra = rng.integers(0, 256, (90, 160, 4), dtype=np.uint8)
    bgra[:, :80, :3] = (40, 40, 200)  # red, blue first
    rgb = bgra[..., 2::-1]
    assert bgra_under(rgb) is bgra
    assert tuple(rgb[0, 0]) == (200, 40, 40)
    for other in (bgra[..., :3], bgra[..., 3:0:-1], bgra[:, 1:, :3]):
        assert bgra_under(other) is None
    for rows, columns in ((slice(0, 45), slice(None)), (slice(None), slice(1, None)),
                          (slice(10, 30), slice(80, 120))):  # fmt: skip
        window = bgra_under(bgra[rows, columns, 2::-1])
        assert window is not None and np.shares_memory(window, bgra)
        assert np.array_equal(window, bgra[rows, columns])
        assert encode_jpeg(bgra[rows, columns, 2::-1]) == encode_jpeg(
            np.ascontiguousarray(bgra[rows, columns, 2::-1])
        )
    assert encode_jpeg(rgb) == encode_jpeg(np.ascontiguousarray(rgb))
    assert encode_jpeg(rgb) != encode_jpeg(np.ascontiguousarray(bgra[..., :3]))
    decoded = cv2_decode(encode_jpeg(rgb, 95))
    assert np.abs(decoded[:, :70].astype(int) - (200, 40, 40)).mean() < 3


def cv2_decode(data: bytes) -> np.ndarray:
    """RGB of JPEG bytes."""
    import cv2

    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]


def test_visible_share_from_depth_agrees_with_the_body_mask(tmp_path):
    """On a synthetic clip's six cameras at six frames, the depth-image share (no mask pass)
    gives the mask's visibility level for at least 95% of the boxes in view, within 0.02 at the
    median, and never calls a box the mask sees fully (>= 0.8) unseen, or the reverse."""
    import dataclasses

    from drivee2e_data import pipeline, store
    from drivee2e_data.sensors.ego_state import ego_motion

    pipeline.synthesize(tmp_path, clips=1, seed=3)
    scenario = store.read_scenario(tmp_path, store.scenario_ids(tmp_path)[0])
    intersection_map = store.read_map(tmp_path, scenario.map_id)
    cameras = [dataclasses.replace(c, width=400, height=225) for c in default_rig().cameras]
    motion = ego_motion(scenario)
    by_mask, by_depth = [], []
    with World(intersection_map, scenario) as world:
        for frame in np.linspace(0, scenario.num_frames - 1, 6).astype(int):
            ego = scenario.ego
            world.place_ego(float(ego.x_m[frame]), float(ego.y_m[frame]), ego.track_id)
            world.set_time(frame)
            ego_to_world = motion.ego_to_world(frame)
            for camera in cameras:
                view = render(world, camera, ego_to_world, mask=True)
                unmasked = dataclasses.replace(view, mask=None)
                for track in scenario.tracks:
                    if track.track_id == scenario.ego_id or not track.valid[frame]:
                        continue
                    body = world.bodies[track.track_id]
                    size = world.blueprints[track.track_id].size_m
                    corners = box_corners_3d(track, frame, size)
                    if projected_area(view, corners, ego_to_world).is_empty:
                        continue
                    by_mask.append(visible_share(view, body, corners, ego_to_world))
                    by_depth.append(visible_share(unmasked, body, corners, ego_to_world))
    by_mask, by_depth = np.array(by_mask), np.array(by_depth)
    seen = (by_mask > 0) | (by_depth > 0)
    assert seen.sum() >= 40
    levels_mask = [visibility_level(v) for v in by_mask[seen]]
    levels_depth = [visibility_level(v) for v in by_depth[seen]]
    assert np.mean(np.equal(levels_mask, levels_depth)) >= 0.95
    assert np.median(np.abs(by_mask - by_depth)[seen]) <= 0.02
    assert not np.any((by_mask >= 0.8) & (by_depth == 0.0))
    assert not np.any((by_depth >= 0.8) & (by_mask == 0.0))


@pytest.mark.parametrize(
    ("renderer", "car_x", "wall_x"), [("gl", 25.0, 14.0), ("tiny", 25.0, 14.0), ("gl", 12.0, 7.0)]
)
def test_a_box_half_hidden_behind_a_wall_reads_about_half_visible(renderer, car_x, wall_x):
    """A wall between the camera and a car 20 m ahead, its edge on the line of sight to the car's
    centre: the half of the box behind it is hidden, the other half seen (with either kind of
    depth: float from the GL renderer, 16-bit from pybullet's). The car 7 m ahead fills enough of
    the image to be sampled on a grid (`annotate._covered_pixels`), and reads the same."""
    from drivee2e_data.sensors.annotate import DEPTH_SAMPLES, projected_area
    from drivee2e_data.sim.gl_context import gl_available

    if renderer == "gl" and not gl_available():
        pytest.skip("no OpenGL context (EGL) here")
    camera_x = 5.0 - 1.4 + default_rig().camera("CAM_FRONT").sensor_to_ego[0, 3]
    # the wall covers y > 0 along the ray from the camera to the car's centre line
    wall = Building("wall", np.array([[wall_x, 0.0], [wall_x + 1.0, 0.0], [wall_x + 1.0, 6.0],
                                      [wall_x, 6.0]]), 8.0)  # fmt: skip
    scenario = small_scenario(FRAMES, tracks=(_parked("ego", 5.0), _parked("hidden", car_x)),
                              ego_id="ego")  # fmt: skip
    shares = {}
    for name, buildings in (("open", ()), ("half", (wall,))):
        world = World(small_map(buildings=buildings), scenario, renderer=renderer)
        try:
            world.place_ego(5.0, 0.0, "ego")
            world.set_time(0)
            ego_to_world = pose(np.eye(3), np.array([5.0 - 1.4, 0.0, 0.0]))
            frame = render(world, default_rig().camera("CAM_FRONT"), ego_to_world, mask=False)
            corners = box_corners_3d(scenario.track("hidden"), 0, world.blueprints["hidden"].size_m)
            shares[name] = visible_share(frame, world.bodies["hidden"], corners, ego_to_world)
            area_px = projected_area(frame, corners, ego_to_world).area
        finally:
            world.close()
    assert camera_x < wall_x
    assert (area_px > 16 * DEPTH_SAMPLES) == (car_x < 20.0)  # the near car: a grid of pixels
    assert shares["open"] > 0.9
    assert 0.35 < shares["half"] < 0.65


def test_a_frames_boxes_are_the_same_from_depth_gathered_at_their_pixels(tmp_path, monkeypatch):
    """The suite chooses each camera's visibility pixels before drawing (`depth_pixels`) and a
    GPU reads the depth there alone; forced here on llvmpipe, a frame's boxes (shares, levels,
    the cameras that see them) are those of the whole depth image, and the views kept no depth
    image. A view with samples but no pixels is refused."""
    from drivee2e_data.sensors import suite as suite_module
    from drivee2e_data.sensors.annotate import visible_shares
    from drivee2e_data.sensors.suite import SensorSuite, SuiteOptions
    from drivee2e_data.sim.gl_context import gl_available

    if not gl_available():
        pytest.skip("no OpenGL context (EGL) here")
    from factories import synthetic_clip

    intersection_map, scenario = synthetic_clip(tmp_path)
    options = SuiteOptions(image_size=(400, 225), lidar="depth")
    frames = np.linspace(0, scenario.num_frames - 1, 3).astype(int)
    views: list = []
    taken = suite_module.render

    def keeping(*args, **kwargs):
        view = taken(*args, **kwargs)
        views.append(view)
        return view

    monkeypatch.setattr(suite_module, "render", keeping)
    with World(intersection_map, scenario, renderer="gl") as world:
        suite = SensorSuite(world, options)
        whole = [suite.capture(int(frame)).boxes for frame in frames]
        assert all(view.depth_m is not None and view.depth_samples is None for view in views)
        world.gl.gathers = True
        views.clear()
        gathered = [suite.capture(int(frame)).boxes for frame in frames]
        assert views and all(view.depth_m is None for view in views)
        assert sum(len(view.depth_samples) for view in views) > 1000
        with pytest.raises(ValueError, match="pixels"):
            visible_shares(views[0], [1], np.zeros((1, 8, 3)), np.eye(4))
    fields = ("track_id", "visible_share", "visibility", "cameras", "num_lidar_points")
    seen = 0
    for ours, expected in zip(gathered, whole, strict=True):
        assert len(ours) == len(expected)
        for box, reference in zip(ours, expected, strict=True):
            assert [getattr(box, f) for f in fields] == [getattr(reference, f) for f in fields]
            seen += box.visible_share > 0
    assert seen >= 5
