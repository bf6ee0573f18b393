"""One ground for every source: scenes offset by +-25 m and sloped by 5% land on the twin's
road (z = 0): boxes on it, cameras above it, LiDAR hits on it at the expected range."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from drivee2e_data.hdmap import Lane
from drivee2e_data.scenario import AgentClass
from drivee2e_data.sources.ground import FLAT, fit_ground, level
from tests.factories import small_map, small_scenario, straight_track

FRAMES = 10
SLOPE = 0.05


def _raised(offset_m: float, slope: float = SLOPE, map_heights: bool = True):
    """A straight road along x with a car and a walker, everything `offset_m + slope x` up;
    without `map_heights` the lanes stay at z = 0 (a source whose map has no heights)."""
    x = np.linspace(-30.0, 80.0, 23)
    height = offset_m + slope * x
    centre = np.column_stack([x, np.zeros_like(x), height if map_heights else np.zeros_like(x)])
    side = np.array([0.0, 1.75, 0.0])
    lane = Lane("l1", centre, centre + side, centre - side, signal_id="s1")
    intersection_map = small_map(lanes=(lane,))
    tracks = []
    for track_id, agent_class, size in (
        ("car", AgentClass.CAR, 1.5),
        ("walker", AgentClass.PEDESTRIAN, 1.7),
    ):
        track = straight_track(track_id, FRAMES, agent_class, height_m=np.full(FRAMES, size))
        z = offset_m + slope * track.x_m + 0.5 * size
        tracks.append(dataclasses.replace(track, z_m=z))
    return intersection_map, small_scenario(FRAMES, tracks=tuple(tracks), ego_id="car")


@pytest.mark.parametrize("offset_m", [25.0, -25.0])
@pytest.mark.parametrize("map_heights", [True, False])
def test_an_offset_sloped_scene_lands_on_the_ground(offset_m: float, map_heights: bool):
    intersection_map, scenario = _raised(offset_m, map_heights=map_heights)
    maps, scenarios, planes = level([intersection_map], [scenario])
    plane = planes[intersection_map.map_id]
    assert plane.source == ("lanes" if map_heights else "vehicles")
    assert plane.slope_x == pytest.approx(SLOPE, abs=1e-6) and plane.height_m == pytest.approx(
        offset_m, abs=1e-6
    )
    for track in scenarios[0].tracks:
        bottom = track.z_m - 0.5 * track.height_m
        assert np.allclose(bottom, 0.0, atol=1e-6), track.track_id  # boxes on the road
    assert np.allclose(maps[0].lanes[0].centerline_m[:, 2], 0.0, atol=1e-6)
    # GNSS still reads the recorded altitude at the origin
    assert maps[0].origin.altitude_m == pytest.approx(intersection_map.origin.altitude_m + offset_m)


def test_a_flat_source_is_left_as_it_is():
    intersection_map, scenario = _raised(0.0, slope=0.0)
    assert fit_ground(intersection_map, [scenario]) is FLAT
    maps, scenarios, _ = level([intersection_map], [scenario])
    assert maps[0] is intersection_map and scenarios[0] is scenario


def test_tracks_already_on_z0_stay_when_only_the_map_carries_elevation():
    """Argoverse 2's forecasting scenarios: lanes at real elevation, tracks without z."""
    intersection_map, _ = _raised(22.9)
    _, on_ground = _raised(0.0, slope=0.0)
    _, scenarios, _ = level([intersection_map], [on_ground])
    for before, after in zip(on_ground.tracks, scenarios[0].tracks, strict=True):
        assert np.array_equal(before.z_m, after.z_m)


def test_cameras_sit_above_the_road_and_lidar_hits_it_at_the_expected_range():
    """The levelled scene in the twin: the ego's front camera sees road below the horizon, and
    the LiDAR's lowest ring (-30 degrees) reaches the road at its mounting height / sin 30."""
    from drivee2e_data.sensors import lidar
    from drivee2e_data.sensors.rig import default_rig
    from drivee2e_data.sensors.suite import SensorSuite
    from drivee2e_data.sim.world import World

    intersection_map, scenario = _raised(-25.0)
    maps, scenarios, _ = level([intersection_map], [scenario])
    with World(maps[0], scenarios[0], renderer="tiny") as world:
        suite = SensorSuite(world)
        ego = scenarios[0].ego
        world.place_ego(float(ego.x_m[5]), float(ego.y_m[5]), ego.track_id)
        world.set_time(5)
        ego_to_world = suite.motion.ego_to_world(5)
        assert ego_to_world[2, 3] == pytest.approx(0.0, abs=1e-6)  # the ego frame on the road
        rig = default_rig()
        lidar_to_world = ego_to_world @ rig.lidar.sensor_to_ego
        sweep = lidar.sweep(world.client, rig.lidar, lidar_to_world, world.twin.segmentation,
                            world.twin.paint_raster())  # fmt: skip
        road = {b for b, k in world.twin.segmentation.items() if k == "road"}
        lowest = (sweep.ring == sweep.ring.max()) & np.isin(sweep.body, list(road))
        assert lowest.sum() > 20
        ranges = np.linalg.norm(sweep.points_m[lowest], axis=1)
        expected = lidar_to_world[2, 3] / np.sin(np.radians(30.0))
        assert np.median(ranges) == pytest.approx(expected, rel=0.02)
        world_points = sweep.points_m[lowest] @ lidar_to_world[:3, :3].T + lidar_to_world[:3, 3]
        assert np.abs(world_points[:, 2]).max() < 0.05  # on the road, not 25 m below it


def test_real_elevation_from_argoverse2_lands_on_the_ground(tmp_path: Path):
    from conftest import REALDATA

    from drivee2e_data import pipeline, store

    source = REALDATA / "argoverse2" / "sensor-log-7fab2350"
    if not source.exists():
        pytest.skip(f"{source} is absent (../shared/realdata)")
    summary = pipeline.import_source(tmp_path, "av2", source)
    plane = summary.grounds[summary.maps[0]]
    assert plane.source == "lanes" and plane.field_rms_m < 0.1
    scenario = store.read_scenario(tmp_path, summary.scenarios[0])
    bottoms = np.concatenate([t.z_m[t.valid] - 0.5 * t.height_m[t.valid] for t in scenario.tracks
                              if t.agent_class.is_motor_vehicle])  # fmt: skip
    assert np.percentile(np.abs(bottoms), 90) < 0.3


def _raise_point(x, z, offset_m: float, slope: float = SLOPE):
    return z + offset_m + slope * x


def _raised_scenarionet(tmp_path: Path, offset_m: float, slope: float) -> Path:
    """A ScenarioNet scene made a Waymo one (whose tracks and map polylines carry elevation,
    where nuScenes' are read flat) with every track and map point at `offset_m + 5% x`."""
    import pickle

    from conftest import REALDATA

    from drivee2e_data.sources.scenarionet import load_pickle

    source = REALDATA / "scenarionet" / "sd_nuscenes_v1.0-mini_scene-0061.pkl"
    if not source.exists():
        pytest.skip(f"{source} is absent (../shared/realdata)")
    scene = load_pickle(source)
    scene["metadata"]["dataset"] = "waymo"
    for feature in scene["map_features"].values():
        for key in ("polyline", "polygon"):
            if key in feature:
                points = np.asarray(feature[key], dtype=np.float64)[:, :2]
                z = _raise_point(points[:, 0], 0.0, offset_m, slope)
                feature[key] = np.column_stack([points, z])
    for track in scene["tracks"].values():
        position = np.array(track["state"]["position"], dtype=np.float64)
        position[:, 2] = _raise_point(position[:, 0], position[:, 2], offset_m, slope)
        track["state"]["position"] = position
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = tmp_path / source.name
    path.write_bytes(pickle.dumps(scene))
    return path


def _raised_argoverse2(tmp_path: Path, offset_m: float, slope: float) -> Path:
    """The Argoverse 2 sensor log with its map, the ego's poses and every box raised by
    `offset_m + 5% x` (x in the city frame; boxes are given in the ego's frame)."""
    import json
    import shutil

    import pyarrow as pa
    import pyarrow.feather as feather
    from conftest import REALDATA

    source = REALDATA / "argoverse2" / "sensor-log-7fab2350"
    if not source.exists():
        pytest.skip(f"{source} is absent (../shared/realdata)")
    folder = tmp_path / source.name
    shutil.copytree(source, folder)
    for path in (folder / "map").glob("log_map_archive_*.json"):
        document = json.loads(path.read_text())

        def lift(value):
            if isinstance(value, dict):
                if {"x", "y", "z"} <= value.keys():
                    value["z"] = float(_raise_point(value["x"], value["z"], offset_m, slope))
                for item in value.values():
                    lift(item)
            elif isinstance(value, list):
                for item in value:
                    lift(item)

        lift(document)
        path.write_text(json.dumps(document))
    poses = feather.read_table(folder / "city_SE3_egovehicle.feather")
    pose_x = poses.column("tx_m").to_numpy()
    lifted = _raise_point(pose_x, poses.column("tz_m").to_numpy(), offset_m, slope)
    index = poses.column_names.index("tz_m")
    feather.write_feather(poses.set_column(index, "tz_m", pa.array(lifted)),
                          folder / "city_SE3_egovehicle.feather")  # fmt: skip
    # a box `dx` ahead of the ego in the city's x sits 5% of `dx` higher than the ego
    pose_at = dict(zip(poses.column("timestamp_ns").to_numpy().tolist(), range(len(pose_x)),
                       strict=True))  # fmt: skip
    boxes = feather.read_table(folder / "annotations.feather")
    rows = np.array([pose_at[t] for t in boxes.column("timestamp_ns").to_numpy().tolist()])
    qw, qz = poses.column("qw").to_numpy()[rows], poses.column("qz").to_numpy()[rows]
    yaw = 2.0 * np.arctan2(qz, qw)
    bx, by = boxes.column("tx_m").to_numpy(), boxes.column("ty_m").to_numpy()
    city_dx = np.cos(yaw) * bx - np.sin(yaw) * by
    box_z = boxes.column("tz_m").to_numpy() + slope * city_dx
    index = boxes.column_names.index("tz_m")
    feather.write_feather(boxes.set_column(index, "tz_m", pa.array(box_z)),
                          folder / "annotations.feather")  # fmt: skip
    return folder


@pytest.mark.slow
@pytest.mark.parametrize("offset_m", [25.0, -25.0])
@pytest.mark.parametrize("kind", ["scenarionet", "av2"])
def test_each_importer_that_reads_z_lands_a_raised_sloped_scene_on_the_ground(
    tmp_path: Path, kind: str, offset_m: float
):
    """Through `drivee2e import`'s own path: a real scene raised by +-25 m and tilted by 5%
    more comes out as the scene as recorded does (lane and track heights within 10 cm:
    the offset and the slope removed, the road's own shape kept; the Argoverse 2 log's boxes,
    given in the ego's frame, were raised by its heading alone), and the Argoverse 2 log's
    vehicles stand on z = 0 (90% of their box bottoms within 0.3 m)."""
    from drivee2e_data import pipeline, store

    raise_scene = _raised_scenarionet if kind == "scenarionet" else _raised_argoverse2
    imported = {}
    # as recorded: the map 1 cm up (a map whose heights are all 0 counts as one without heights)
    for name, offset, slope in (("as recorded", 0.01, 0.0), ("raised", offset_m, SLOPE)):
        source = raise_scene(tmp_path / name / "source", offset, slope)
        root = tmp_path / name / "data"
        summary = pipeline.import_source(root, kind, source)
        assert summary.grounds[summary.maps[0]].source == "lanes"
        scenarios = [store.read_scenario(root, s) for s in summary.scenarios]
        imported[name] = (store.read_map(root, summary.maps[0]), scenarios)
    (map_a, clips_a), (map_b, clips_b) = imported["as recorded"], imported["raised"]
    lanes_a = np.concatenate([lane.centerline_m[:, 2] for lane in map_a.lanes])
    lanes_b = np.concatenate([lane.centerline_m[:, 2] for lane in map_b.lanes])
    assert np.abs(lanes_b - lanes_a).max() < 0.1
    assert [c.scenario_id for c in clips_a] == [c.scenario_id for c in clips_b]
    for a, b in zip(clips_a, clips_b, strict=True):
        raised = {t.track_id: t for t in b.tracks}
        differences, total = [], 0
        for track_a in a.tracks:
            track_b = raised[track_a.track_id]
            # the sensor log's boxes at the edge of its range come and go by a frame or so,
            # and their first resampled frame moves a little with them
            valid = track_a.valid & track_b.valid
            differences.append(np.abs(track_b.z_m[valid] - track_a.z_m[valid]))
            total += track_a.valid.sum()
        differences = np.concatenate(differences)
        assert len(differences) >= 0.95 * total
        assert np.percentile(differences, 95) < 0.1 and differences.max() < 0.3
        if kind == "av2":
            bottoms = np.concatenate([t.z_m[t.valid] - 0.5 * t.height_m[t.valid]
                                      for t in b.tracks if t.agent_class.is_motor_vehicle])  # fmt: skip
            assert np.percentile(np.abs(bottoms), 90) < 0.3, b.scenario_id


@pytest.mark.parametrize("offset_m", [25.0, -25.0])
def test_a_lanelet2_map_with_raised_sloped_ele_tags_lands_on_the_ground(
    tmp_path: Path, offset_m: float
):
    """The shared Lanelet2 example (nearly flat: 4 of its 2258 nodes carry an `ele`) given `ele` tags 25 m up
    or down and rising 5% eastwards imports with its lanes back at z = 0 (within 5 cm)."""
    import math
    import re

    from conftest import REALDATA

    from drivee2e_data import pipeline, store

    source = REALDATA / "lanelet2" / "mapping_example.osm"
    if not source.exists():
        pytest.skip(f"{source} is absent (../shared/realdata)")
    text = re.sub(r"<tag k='ele' v='[^']*'\s*/>", "", source.read_text())  # 4 nodes have one
    first_lon = float(re.search(r"lon='([-\d.]+)'", text).group(1))

    def with_ele(match: re.Match) -> str:
        attributes, closed = match.group(1), match.group(2)
        lat = float(re.search(r"lat='([-\d.]+)'", attributes).group(1))
        lon = float(re.search(r"lon='([-\d.]+)'", attributes).group(1))
        east_m = (lon - first_lon) * 111_320.0 * math.cos(math.radians(lat))
        tag = f"<tag k='ele' v='{offset_m + SLOPE * east_m:.4f}'/>"
        return f"<node {attributes}>{tag}" + ("</node>" if closed else "")

    raised = re.sub(r"<node ([^>]*?)\s*(/?)>", with_ele, text)
    assert raised.count("k='ele'") == text.count("<node")
    path = tmp_path / "raised.osm"
    path.write_text(raised)
    summary = pipeline.import_source(tmp_path / "data", "lanelet2", path)
    plane = summary.grounds[summary.maps[0]]
    assert plane.source == "lanes" and plane.slope_x == pytest.approx(SLOPE, abs=0.005)
    intersection_map = store.read_map(tmp_path / "data", summary.maps[0])
    lane_z = np.concatenate([lane.centerline_m[:, 2] for lane in intersection_map.lanes])
    assert np.abs(lane_z).max() < 0.05
