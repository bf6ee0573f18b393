"""The LiDAR: known answers on flat ground with one box."""

import numpy as np
import pybullet
import pytest

from drivee2e_data.sensors.lidar import (
    INTENSITY,
    POINTS_PER_M,
    beam_directions,
    on_grid,
    ranges_per_beam,
    sweep,
)
from drivee2e_data.sensors.rig import default_rig, pose

HEIGHT_M = 1.85  # the rig's LiDAR mount height


@pytest.fixture
def scene():
    client = pybullet.connect(pybullet.DIRECT)
    ground = pybullet.createCollisionShape(
        pybullet.GEOM_BOX, halfExtents=[200, 200, 0.5], physicsClientId=client
    )
    ground_body = pybullet.createMultiBody(0, ground, -1, [0, 0, -0.5], physicsClientId=client)
    box = pybullet.createCollisionShape(
        pybullet.GEOM_BOX, halfExtents=[1.0, 1.0, 1.5], physicsClientId=client
    )
    box_body = pybullet.createMultiBody(
        0, box, -1, [21.0, 0.0, 1.5], physicsClientId=client
    )  # front face at x = 20
    yield client, {ground_body: "road"}, box_body
    pybullet.disconnect(client)


def test_beam_layout():
    directions, ring = beam_directions(default_rig().lidar)
    assert directions.shape == (64 * 1800, 3) and np.allclose(
        np.linalg.norm(directions, axis=1), 1.0
    )
    assert ring.max() == 63 and np.rad2deg(np.arcsin(directions[0, 2])) == pytest.approx(10.0)


def test_points_are_given_to_the_nearest_1024th_of_a_metre():
    """The grid a real LiDAR's range steps stand for: 20.0004 m is 20 m; -1.2345 m is
    -1264/1024 = -1.234375 m; 0.48 mm is 0 and 0.49 mm one step; exact in float32."""
    assert POINTS_PER_M == 1024
    grid = on_grid(np.array([[20.0004, -1.2345, 0.0], [84.9999, 0.00048, 0.00049]]))
    assert grid.dtype == np.float32
    assert grid.tolist() == [[20.0, -1.234375, 0.0], [85.0, 0.0, 1 / 1024]]


def test_box_20m_ahead_and_ground_rings(scene):
    client, kinds, box_body = scene
    lidar = default_rig().lidar
    sensor_to_world = pose(np.eye(3), np.array([0.0, 0.0, HEIGHT_M]))
    result = sweep(client, lidar, sensor_to_world, kinds)
    on_box = result.body == box_body
    ahead = on_box & (np.abs(result.points_m[:, 1]) < 0.3)
    assert ahead.sum() > 10
    assert np.abs(result.points_m[ahead, 0] - 20.0).max() < 0.02  # +- 2 cm
    steps = result.points_m.astype(np.float64) * POINTS_PER_M
    assert np.array_equal(steps, np.rint(steps))  # every point on the grid
    ground = result.body != box_body
    elevations = default_rig().lidar.elevations_rad[result.ring[ground]]
    expected_range = HEIGHT_M / np.sin(-elevations)
    measured_range = np.linalg.norm(result.points_m[ground], axis=1)
    assert np.abs(measured_range - expected_range).max() < 0.02
    assert (elevations < 0).all()  # upward beams hit nothing on flat ground
    assert np.allclose(result.intensity[ground], INTENSITY["road"])
    rings_on_ground = np.unique(result.ring[ground])
    assert len(rings_on_ground) > 40


def test_sweep_in_a_twin_sees_road_paint_and_agents(tmp_path):
    from drivee2e_data import pipeline, store
    from drivee2e_data.sim.world import World

    pipeline.synthesize(tmp_path, clips=1, seed=3)
    scenario = store.read_scenario(tmp_path, store.scenario_ids(tmp_path)[0])
    with World(store.read_map(tmp_path, scenario.map_id), scenario, renderer="tiny") as world:
        ego = scenario.ego
        frame = 20
        world.place_ego(float(ego.x_m[frame]), float(ego.y_m[frame]), ego.track_id)
        world.set_time(frame)
        c, s = np.cos(ego.yaw_rad[frame]), np.sin(ego.yaw_rad[frame])
        sensor_to_world = pose(
            np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]),
            np.array([ego.x_m[frame], ego.y_m[frame], HEIGHT_M]),
        )
        kinds = world.twin.segmentation
        result = sweep(
            world.client, default_rig().lidar, sensor_to_world, kinds, world.twin.paint_raster()
        )
    hit_kinds = {kinds.get(int(b), "agent") for b in result.body}
    assert {"road", "agent"} <= hit_kinds
    # markings are drawn only: their returns are road hits on painted cells, brighter
    assert not {"road_mark", "crosswalk", "stop_line"} & hit_kinds
    on_road = np.isin(result.body, [b for b, k in kinds.items() if k == "road"])
    painted = result.intensity[on_road] == INTENSITY["road_mark"]
    assert 0.002 < painted.mean() < 0.2
    raster = world.twin.paint_raster()
    crosswalk = world.intersection_map.crosswalks[0].polygon_m.mean(axis=0)
    assert raster.kinds[raster.kind_codes(crosswalk[None])[0] - 1] == "crosswalk"
    assert raster.kind_codes(np.array([[1e4, 1e4]]))[0] == 0  # off the raster: no paint
    assert len(result.points_m) > 50_000  # most downward beams return


@pytest.mark.slow
def test_depth_image_lidar_agrees_with_ray_casting(tmp_path):
    """The same frame of a synthetic twin swept both ways: ranges on hits both see within 2 cm
    (median), the same rings, and the same number of points on every box with 50 or more."""
    from drivee2e_data import pipeline, store
    from drivee2e_data.sensors.lidar_depth import depth_sweep
    from drivee2e_data.sensors.suite import SensorSuite
    from drivee2e_data.sim.world import World

    pipeline.synthesize(tmp_path, clips=1, seed=0)
    scenario = store.read_scenario(tmp_path, store.scenario_ids(tmp_path)[0])
    with World(store.read_map(tmp_path, scenario.map_id), scenario) as world:
        suite = SensorSuite(world)
        frame, ego, lidar = 80, scenario.ego, suite.rig.lidar
        world.place_ego(float(ego.x_m[frame]), float(ego.y_m[frame]), ego.track_id)
        world.set_time(frame)
        sensor_to_world = suite.motion.ego_to_world(frame) @ lidar.sensor_to_ego
        paint = world.twin.paint_raster()
        cast = sweep(world.client, lidar, sensor_to_world, world.twin.segmentation, paint)
        read = depth_sweep(world, lidar, sensor_to_world, paint)
        agents = set(world.bodies.values())
        two_wheeled = ("cyclist", "motorcyclist", "tricyclist")
        solid = {world.bodies[t.track_id] for t in scenario.tracks
                 if t.agent_class.value not in two_wheeled}  # fmt: skip
    cast_range = ranges_per_beam(cast, lidar)
    read_range = ranges_per_beam(read, lidar)
    both = np.isfinite(cast_range) & np.isfinite(read_range)
    assert both.sum() > 0.99 * min(len(cast.ring), len(read.ring))
    assert np.median(np.abs(cast_range[both] - read_range[both])) < 0.02
    assert set(np.unique(cast.ring)) == set(np.unique(read.ring))
    counted = 0
    for body in agents:
        expected = int((cast.body == body).sum())
        if expected >= 50:
            # ray casting hits the convex parts of the models (`actors.convex_parts`), the depth
            # images their triangles: the same on solid bodies; a two-wheeler's spoked wheels
            # and open frame are discs and hulls to the rays, so the images see fewer points
            tolerance = 0.05 if body in solid else 0.3
            assert abs(int((read.body == body).sum()) - expected) <= tolerance * expected, body
            counted += body in solid
    assert counted >= 3
    # paint is seen directly: its returns carry the markings' reflectivity, as ray casting's do
    assert np.isclose(read.intensity, INTENSITY["road_mark"]).mean() == pytest.approx(
        np.isclose(cast.intensity, INTENSITY["road_mark"]).mean(), abs=0.01
    )


def test_road_and_its_markings_are_one_surface_for_the_depth_lidar():
    """Paint lies within a centimetre of the road: a beam between asphalt and paint pixels is
    interpolated, not cast; every other body (and nothing, -1) is a surface of its own."""
    from types import SimpleNamespace

    from drivee2e_data.sensors.lidar_depth import _surfaces

    kinds = {0: "ground", 1: "road", 2: "road_mark", 3: "crosswalk", 4: "building", 5: "stop_line"}
    world = SimpleNamespace(bodies={"car": 6, "bus": 7}, twin=SimpleNamespace(segmentation=kinds))
    surface = _surfaces(world)
    assert surface.tolist() == [-1, 0, 1, 1, 1, 4, 1, 6, 7]  # indexed by mask value + 1


def test_depth_lidar_edges_take_the_side_the_beam_falls_on_and_cast_only_at_agents():
    """Four beams over one 2x2 block of a 2x3 view. Columns 0-1 show a wall (body 4) at 10 m
    and 12 m, column 2 a tree (body 5) at 5 m; an agent (body 6) is at row 1, column 2 in the
    second block. A beam three quarters of the way towards the wall takes the wall's inverse
    depth interpolated over the wall's pixels alone and the wall's body, with no ray; a beam
    by the tree takes the tree; one on a single surface is interpolated as before; one whose
    block shows the agent is to be cast."""
    from types import SimpleNamespace

    from drivee2e_data.sensors.lidar_depth import _agents, _sample, _Samples, _surfaces

    depth = np.array([[10.0, 12.0, 5.0], [10.0, 12.0, 5.0]], np.float32)
    mask = np.array([[4, 4, 5], [4, 4, 5]], np.int32)
    agent_mask = np.array([[4, 4, 5], [4, 4, 6]], np.int32)
    kinds = {4: "building", 5: "vegetation"}
    world = SimpleNamespace(bodies={"ego": 0, "car": 6}, twin=SimpleNamespace(segmentation=kinds))
    surface = _surfaces(world)
    agent = _agents(world, len(surface))
    left, right = [0, 1, 3, 4], [1, 2, 4, 5]  # flat pixel indices of the two 2x2 blocks

    def weights(dx: float) -> list[float]:  # half-way down, `dx` along the row
        return [(1 - dx) / 2, dx / 2, (1 - dx) / 2, dx / 2]

    samples = _Samples(
        beams=np.arange(4),
        corners=np.array([left, right, right, right]).T,
        weights=np.array([weights(0.5), weights(0.25), weights(0.75), weights(0.75)]).T,
        nearest=np.array([0, 0, 1, 1]),
        along=np.ones(4),
    )
    got, body, reach = _sample(depth, mask, samples, surface, agent)
    assert got[0] == pytest.approx(1 / (0.5 / 10 + 0.5 / 12))  # one surface: as before
    assert got[1] == pytest.approx(12.0) and body[1] == 4  # the wall's side of the edge
    assert got[2] == pytest.approx(5.0) and body[2] == 5  # the tree's side
    assert np.isnan(reach).all()  # the twin's own edges need no ray
    got, body, reach = _sample(depth, agent_mask, samples, surface, agent)
    # every block touching the agent is cast as far as the agent's pixel (5 m) ...
    assert np.isnan(reach[0]) and reach[1:].tolist() == [5.0, 5.0, 5.0]
    # ... and takes what lies behind the agent's pixel where the ray hits nothing that far: the
    # wall by the wall's side, the tree (its upper pixel) by the tree's
    assert got[1] == pytest.approx(12.0) and body[1] == 4
    assert got[3] == pytest.approx(5.0) and body[3] == 5


def test_depth_lidar_casts_a_beam_between_agents_alone_all_the_way():
    """A beam whose four pixels show two agents has no surface behind to fall back on: its
    depth is unknown and it is marked to be cast the whole range; its reach is the farther
    agent's depth."""
    from types import SimpleNamespace

    from drivee2e_data.sensors import lidar_depth

    depth = np.array([[7.0, 9.0], [7.0, 9.0]], np.float32)
    mask = np.array([[6, 7], [6, 7]], np.int32)
    world = SimpleNamespace(bodies={"car": 6, "bus": 7}, twin=SimpleNamespace(segmentation={}))
    surface = lidar_depth._surfaces(world)
    agent = lidar_depth._agents(world, len(surface))
    samples = lidar_depth._Samples(
        beams=np.arange(1),
        corners=np.array([[0, 1, 2, 3]]).T,
        weights=np.array([[0.25, 0.25, 0.25, 0.25]]).T,
        nearest=np.array([0]),
        along=np.ones(1),
    )
    got, body, reach = lidar_depth._sample(depth, mask, samples, surface, agent)
    assert np.isnan(got[0]) and body[0] == lidar_depth.CAST_THROUGH
    assert reach[0] == pytest.approx(9.0)


def test_paint_codes_are_read_by_cell_and_none_off_the_raster():
    """A 2 x 3 raster of 0.5 m cells from (10, 20): each point reads its cell's code, row by y
    and column by x; a point just outside any edge reads 0."""
    from drivee2e_data.sim.twin import PaintRaster

    codes = np.array([[1, 2, 3], [4, 5, 6]], np.uint8)
    raster = PaintRaster(np.array([10.0, 20.0]), 0.5, codes)
    inside = np.array([[10.1, 20.1], [11.4, 20.2], [10.6, 20.9], [11.49, 20.99]])
    assert raster.kind_codes(inside).tolist() == [1, 3, 5, 6]
    outside = np.array([[9.99, 20.1], [11.5, 20.1], [10.1, 19.99], [10.1, 21.0]])
    assert raster.kind_codes(outside).tolist() == [0, 0, 0, 0]
    assert raster.kind_codes(np.zeros((0, 2))).tolist() == []
