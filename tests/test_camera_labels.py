"""Dense camera labels with known answers: a car 20 m ahead reads 20 m at its pixels, its
instance pixels lie in its projected box, a crosswalk is labelled crosswalk where the camera
sees it; and the labels travel through the log into the Dataset."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from drivee2e_data import store
from drivee2e_data.cli import main
from drivee2e_data.hdmap import Area, Crosswalk
from drivee2e_data.loaders import DriveE2EDataset, collate
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.scenario import AgentClass
from drivee2e_data.sensors.camera import camera_to_world
from drivee2e_data.sensors.camera_labels import SEMANTIC_CLASSES, decode_png
from drivee2e_data.sensors.ego_state import ego_motion
from drivee2e_data.sensors.suite import SensorSuite, SuiteOptions
from drivee2e_data.sim.world import World
from tests.conftest import copy_clips
from tests.factories import small_map, small_scenario, straight_track

FRAMES = 5
WIDTH, HEIGHT = 320, 180
EGO_LENGTH_M = 4.5  # the ego track's box; its rear axle sits 0.3 lengths behind the centre
CAMERA_X_M = -0.3 * EGO_LENGTH_M + 1.70  # CAM_FRONT's mount, world x at frame 0
LEAD_LENGTH_M = 4.6  # the sedan blueprint the lead car's 4.5 m box is drawn with
CROSSWALK_X_M = (CAMERA_X_M + 8.0, CAMERA_X_M + 11.0)


@pytest.fixture(scope="module")
def labelled_frame():
    """CAM_FRONT at 320x180, labels at full resolution, of an ego whose camera sees a car's
    rear face exactly 20 m ahead and a crosswalk 8-11 m ahead."""
    ego = straight_track("ego", FRAMES, x_m=np.zeros(FRAMES), vx_mps=np.zeros(FRAMES))
    lead_x = CAMERA_X_M + 20.0 + LEAD_LENGTH_M / 2
    lead = straight_track("lead", FRAMES, x_m=np.full(FRAMES, lead_x), vx_mps=np.zeros(FRAMES))
    walker = straight_track("walker", FRAMES, AgentClass.PEDESTRIAN, y_m=np.full(FRAMES, 30.0))
    scenario = small_scenario(FRAMES, tracks=(ego, lead, walker), ego_id="ego")
    x0, x1 = CROSSWALK_X_M
    crosswalk = Crosswalk("cw", np.array([[x0, -1.75], [x1, -1.75], [x1, 1.75], [x0, 1.75]]))
    road = Area("road", np.array([[-10.0, -1.75], [60.0, -1.75], [60.0, 1.75], [-10.0, 1.75]]))
    intersection_map = small_map(drivable_areas=(road,), crosswalks=(crosswalk,))
    options = SuiteOptions(cameras=("CAM_FRONT",), image_size=(WIDTH, HEIGHT),
                           camera_labels=("depth", "semantic", "instance"), label_scale=1)  # fmt: skip
    with World(intersection_map, scenario) as world:
        suite = SensorSuite(world, options)
        frame = suite.capture(0)
        camera = suite.rig.cameras[0]
        pose = camera_to_world(camera, ego_motion(scenario).ego_to_world(0))
        images = {kind: decode_png(png) for kind, png in frame.camera_labels["CAM_FRONT"].items()}
        return images, suite.instance_index, camera, pose, crosswalk


def test_label_images_have_the_camera_size_and_types(labelled_frame) -> None:
    images, *_ = labelled_frame
    assert images["depth"].shape == (HEIGHT, WIDTH) and images["depth"].dtype == np.uint16
    assert images["semantic"].dtype == np.uint8 and images["instance"].dtype == np.uint16
    assert (images["semantic"] == SEMANTIC_CLASSES.index("sky")).any()  # above the horizon


def test_depth_of_a_car_20_m_ahead_reads_20_m(labelled_frame) -> None:
    images, index, *_ = labelled_frame
    car = images["instance"] == index["lead"] + 1
    assert car.sum() > 50
    depth_m = images["depth"][car] / 1000.0
    # the box's rear face is 20 m down the optical axis: the bumper and lamps reach it, the
    # body, boot lid and rear window stand further back, all within the box's length
    assert depth_m.min() == pytest.approx(20.0, abs=0.02)
    assert np.percentile(depth_m, 5) == pytest.approx(20.0, abs=0.05)
    assert depth_m.max() <= 20.0 + 4.6 and 20.0 < np.median(depth_m) < 20.0 + 2.3
    assert (images["semantic"][car] == SEMANTIC_CLASSES.index("car")).all()


def test_instance_pixels_lie_in_the_projected_box(labelled_frame) -> None:
    images, index, camera, pose, _ = labelled_frame
    lead_x = CAMERA_X_M + 20.0 + LEAD_LENGTH_M / 2
    half = np.array([LEAD_LENGTH_M / 2, 1.85 / 2])
    corners = np.array(
        [
            [lead_x + sx * half[0], sy * half[1], z]
            for sx in (-1, 1)
            for sy in (-1, 1)
            for z in (0.0, 1.45)
        ]
    )
    in_camera = (np.column_stack([corners, np.ones(8)]) @ np.linalg.inv(pose).T)[:, :3]
    pixels = (camera.intrinsic @ in_camera.T).T
    pixels = pixels[:, :2] / pixels[:, 2:3]
    rows, columns = np.nonzero(images["instance"] == index["lead"] + 1)
    u, v = columns + 0.5, rows + 0.5  # pixel centres
    assert (u >= pixels[:, 0].min() - 1).all() and (u <= pixels[:, 0].max() + 1).all()
    assert (v >= pixels[:, 1].min() - 1).all() and (v <= pixels[:, 1].max() + 1).all()
    assert not (images["instance"] == index["walker"] + 1).any()  # 30 m to the side: unseen


def test_crosswalk_pixels_are_on_the_crosswalk(labelled_frame) -> None:
    images, _, camera, pose, crosswalk = labelled_frame
    marked = images["semantic"] == SEMANTIC_CLASSES.index("crosswalk")
    assert marked.sum() > 100
    rows, columns = np.nonzero(marked)
    depth = images["depth"][rows, columns] / 1000.0
    inverse_k = np.linalg.inv(camera.intrinsic)
    rays = (inverse_k @ np.vstack([columns + 0.5, rows + 0.5, np.ones(len(rows))])).T
    world = (np.column_stack([rays * depth[:, None], np.ones(len(rows))]) @ pose.T)[:, :3]
    area = shapely.Polygon(crosswalk.polygon_m).buffer(0.1)
    assert shapely.contains_xy(area, world[:, 0], world[:, 1]).all()
    # and the crosswalk's middle, which the camera sees unoccluded, is labelled crosswalk
    middle = np.array([np.mean(CROSSWALK_X_M), 0.0, 0.0, 1.0]) @ np.linalg.inv(pose).T
    u, v = (camera.intrinsic @ middle[:3])[:2] / middle[2]
    assert images["semantic"][int(v), int(u)] == SEMANTIC_CLASSES.index("crosswalk")


def test_labels_through_the_log_into_the_dataset(synthetic_root, tmp_path) -> None:
    (clip,) = store.scenario_ids(synthetic_root)[:1]
    root = copy_clips(synthetic_root, tmp_path / "data", [clip])
    code = main(["collect", str(root), "--max-frames", "2", "--image-size", "160x90",
                 "--camera-labels", "depth,semantic,instance", "--label-scale", "2"])  # fmt: skip
    assert code == 0 and main(["logs", str(root), "--validate"]) == 0
    with LogReader(root / "logs" / f"{clip}.mcap") as log:
        info = log.camera_label_info
        assert info["size"] == (80, 45) and info["scale"] == 2
        assert info["semantic_classes"] == SEMANTIC_CLASSES
    assert main(["split", str(root)]) == 0
    dataset = DriveE2EDataset(root, "all", image_size=(160, 90), with_map=False,
                              camera_labels=("depth", "semantic", "instance"))  # fmt: skip
    batch = collate([dataset[0], dataset[1]])
    assert batch["cam_depth"].shape == (2, 6, 90, 160) and batch["cam_depth"].max() > 10.0
    assert batch["cam_semantic"].shape == (2, 6, 90, 160)
    values = set(batch["cam_instance"].unique().tolist()) - {0}
    ids = batch["cam_instance_ids"][0]
    assert all(ids[v - 1] in store.read_scenario(root, clip).track_ids for v in values)
    plain = DriveE2EDataset(root, "all", with_map=False)
    assert "cam_depth" not in plain[0]
    with pytest.raises(ValueError, match="not one of"):
        DriveE2EDataset(root, "all", camera_labels=("normals",))
    # the nuScenes export reads such logs as any other (the label topics are not its business)
    assert main(["export", "nuscenes", str(root), "--out", str(tmp_path / "nuscenes")]) == 0


@pytest.mark.slow
def test_map_dividers_lie_on_the_rendered_paint(synthetic_scenarios, synthetic_root) -> None:
    """Across each divider label, every 0.5 m, the painted line's middle (single or double)
    is within 10 cm of the label; dashes leave gaps, so a third of the points at least."""
    from drivee2e_data.loaders.map_labels import MAP_CLASSES, map_elements

    scenario = synthetic_scenarios[0]
    intersection_map = store.read_map(synthetic_root, scenario.map_id)
    elements = map_elements(intersection_map)
    with World(intersection_map, scenario) as world:
        paint = shapely.union_all([g for kind, g in world.twin.paint if kind == "road_mark"])
    divider = MAP_CLASSES.index("divider")
    checked = 0
    for polyline, label in zip(elements.polylines_m, elements.labels, strict=True):
        if label != divider:
            continue
        line = shapely.LineString(polyline)
        offsets, hits = [], 0
        distances = np.arange(0.25, line.length - 0.25, 0.5)
        for s in distances:
            a, b = line.interpolate(s - 0.05), line.interpolate(s + 0.05)
            direction = np.array([b.x - a.x, b.y - a.y])
            normal = np.array([-direction[1], direction[0]]) / np.linalg.norm(direction)
            point = np.array(line.interpolate(s).coords[0])
            across = shapely.LineString([point - 0.4 * normal, point + 0.4 * normal])
            painted = across.intersection(paint)
            if painted.is_empty:
                continue
            hits += 1
            ends = np.asarray(shapely.get_coordinates(painted)) - point
            along_normal = ends @ normal
            offsets.append(0.5 * (along_normal.min() + along_normal.max()))
        assert hits >= len(distances) / 3 - 1, hits
        assert np.max(np.abs(offsets)) <= 0.10
        checked += 1
    assert checked >= 4
