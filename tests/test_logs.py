"""The MCAP contract: plain readers open a log, every topic at every frame, random access by
frame, validation naming the gap, the future path read back equal to the scenario's."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from drivee2e_data import store
from drivee2e_data.errors import LogFormatError
from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.sensors.ego_state import ego_motion, future_path

PLAIN_READER = r"""
import json, sys
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
counts, schemas, times = {}, {}, {}
with open(sys.argv[1], "rb") as stream:
    reader = make_reader(stream, decoder_factories=[DecoderFactory()])
    for schema, channel, message, decoded in reader.iter_decoded_messages():
        counts[channel.topic] = counts.get(channel.topic, 0) + 1
        schemas[channel.topic] = schema.name
        times.setdefault(channel.topic, []).append(message.log_time)
        if channel.topic == "/CAM_FRONT/image_compressed":
            image = CompressedImage.FromString(message.data)
            assert image.format == "jpeg" and image.data[:2] == b"\xff\xd8"
        if channel.topic == "/LIDAR_TOP":
            cloud = PointCloud.FromString(message.data)
            lidar = ([f.name for f in cloud.fields], cloud.point_stride, len(cloud.data))
        if channel.topic == "/ego/state":
            ego_speed = decoded.speed
    metadata = sorted(record.name for record in reader.iter_metadata())
print(json.dumps({"counts": counts, "schemas": schemas, "times": times, "lidar": lidar,
                  "metadata": metadata, "ego_speed": ego_speed,
                  "project_code": any(m.startswith("drivee2e") for m in sys.modules)}))
"""


def _log(root: Path, index: int = 0) -> Path:
    return sorted((root / "logs").glob("*.mcap"))[index]


def test_a_log_opens_with_plain_mcap_and_foxglove_classes(collected_root: Path):
    path = _log(collected_root)
    output = subprocess.run(
        [sys.executable, "-c", PLAIN_READER, str(path)], capture_output=True, text=True, check=True
    )
    found = json.loads(output.stdout)
    assert not found["project_code"]
    expected = set(topics.per_frame_topics())
    assert set(found["counts"]) == expected | {topics.MAP}
    frames = found["counts"][topics.EGO_STATE]
    assert frames == 36
    assert all(found["counts"][t] == frames for t in expected) and found["counts"]["/map"] == 1
    frame_times = found["times"][topics.EGO_STATE]
    assert all(found["times"][t] == frame_times for t in expected)  # one log_time per frame
    assert np.all(np.diff(frame_times) == 100_000_000)  # 10 Hz
    assert found["schemas"]["/CAM_BACK/image_compressed"] == "foxglove.CompressedImage"
    assert found["schemas"]["/CAM_BACK/camera_info"] == "foxglove.CameraCalibration"
    assert found["schemas"]["/RADAR_FRONT"] == "foxglove.PointCloud"
    assert found["schemas"]["/tf"] == "foxglove.FrameTransforms"
    assert found["schemas"]["/gnss"] == "foxglove.LocationFix"
    assert found["schemas"]["/annotations/scene"] == "foxglove.SceneUpdate"
    assert found["schemas"]["/annotations/objects"] == "drivee2e.ObjectAnnotations"
    names, stride, size = found["lidar"]
    assert names == ["x", "y", "z", "intensity", "ring"] and stride == 17
    assert size % stride == 0 and size // stride > 30_000  # a full sweep hits the ground
    assert found["ego_speed"] > 0
    assert found["metadata"] == sorted(
        [
            topics.SCENARIO_METADATA,
            topics.RIG_METADATA,
            topics.COLLECTION_METADATA,
            topics.FRAMES_METADATA,
        ]
    )


def test_validation_passes_and_the_cli_lists_logs(collected_root: Path, capsys):
    from drivee2e_data.cli import main

    assert main(["logs", str(collected_root), "--validate"]) == 0
    out = capsys.readouterr().out
    assert "2 logs" in out and out.count("valid") == 2


def _copy_without(
    source: Path, target: Path, topic: str, frame: int, drop_topics=lambda topic: False
) -> None:  # type: ignore[no-untyped-def]
    """Rewrite a log, leaving out `topic`'s message at `frame` (counted from the first), and
    every topic `drop_topics` names (channels and all)."""
    with open(source, "rb") as stream, open(target, "wb") as out:
        reader = make_reader(stream)
        writer = Writer(out)
        writer.start()
        schemas, channels, times = {}, {}, []
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            if drop_topics(channel.topic):
                continue
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id]
                )
            if message.log_time not in times:
                times.append(message.log_time)
            if channel.topic == topic and times.index(message.log_time) == frame:
                continue
            writer.add_message(
                channels[channel.id], message.log_time, message.data, message.publish_time
            )
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
        writer.finish()


def test_a_missing_message_is_named_by_topic_and_frame(collected_root: Path, tmp_path: Path):
    broken = tmp_path / "broken.mcap"
    _copy_without(_log(collected_root, 1), broken, topics.LIDAR, 3)
    with LogReader(broken) as log, pytest.raises(LogFormatError) as caught:
        log.validate()
    message = str(caught.value)
    assert "broken.mcap" in message and "/LIDAR_TOP" in message and "frame 3" in message


def test_each_cameras_exposure_is_logged_beside_its_image(collected_root: Path, tmp_path: Path):
    """Every sensor frame logs each camera's exposure, and the image shows it: as drawn at gain
    1 (its mean grey the metered one), else just inside the band (this clip's overcast dawn
    raises every camera; the back ones reach the gain's limit); a log of an older look, without
    the topic, still validates, and a missing exposure message is named."""
    import cv2

    from drivee2e_data.sim.conditions import EXPOSURE_AIM

    path = _log(collected_root)
    gains: list[float] = []
    with LogReader(path) as log:
        for frame in log.sensor_frames[:3]:
            for camera in log.cameras:
                wanted = [topics.image_topic(camera), topics.exposure_topic(camera)]
                messages = log.frame(frame, wanted)
                exposed = messages[topics.exposure_topic(camera)]
                assert exposed.frame_id == camera and 0.5 <= exposed.gain <= 3.0
                image = cv2.imdecode(
                    np.frombuffer(messages[topics.image_topic(camera)].data, np.uint8),
                    cv2.IMREAD_GRAYSCALE,
                )
                mean = float(image.mean())
                gains.append(exposed.gain)
                if exposed.gain == 1.0:  # as drawn: the meter read the image's mean
                    assert abs(mean - exposed.metered) < 2.0, (frame, camera)
                elif 0.5 < exposed.gain < 3.0:  # brought just inside the band (82 or 98)
                    aim = EXPOSURE_AIM[0] if exposed.gain > 1.0 else EXPOSURE_AIM[1]
                    assert abs(mean - aim) < 2.0, (frame, camera)
                else:  # the gain's limit: as near as it goes
                    assert mean < EXPOSURE_AIM[0] + 2.0 if exposed.gain == 3.0 else mean > 96.0
                    assert exposed.gain in (0.5, 3.0)
    assert any(1.0 < g < 3.0 for g in gains) and 3.0 in gains  # both branches seen
    dropped = tmp_path / "dropped.mcap"
    _copy_without(path, dropped, "/CAM_BACK/exposure", 2)
    with LogReader(dropped) as log, pytest.raises(LogFormatError) as caught:
        log.validate()
    assert "/CAM_BACK/exposure" in str(caught.value) and "frame 2" in str(caught.value)
    without = tmp_path / "without.mcap"
    _copy_without(path, without, "", -1, drop_topics=lambda topic: topic.endswith("/exposure"))
    with LogReader(without) as log:
        log.validate()  # logs before look 10 carry no exposure


def test_a_truncated_log_is_refused_clearly(collected_root: Path, tmp_path: Path):
    data = _log(collected_root, 1).read_bytes()
    truncated = tmp_path / "cut.mcap"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(LogFormatError, match=r"cut\.mcap"):
        LogReader(truncated)


def test_metadata_read_through_the_summary_offsets_equals_the_whole_summarys(
    collected_root: Path, tmp_path: Path
):
    """A log opens reading only its metadata (through the summary offsets); a log without
    summary offsets (another writer) opens through its whole summary, to the same values."""
    data = bytearray(_log(collected_root, 1).read_bytes())
    with LogReader(_log(collected_root, 1)) as log:
        assert log._summary is None  # not parsed to open the log
        fast, frames = log.metadata, log.frame(log.first_frame + 5)
        assert len(log.summary.chunk_indexes) > 0 and log._summary is not None  # on first use
    # the footer's summary-offset start (8 bytes before its CRC and the closing magic) zeroed
    data[-20:-12] = bytes(8)
    plain = tmp_path / "no_offsets.mcap"
    plain.write_bytes(bytes(data))
    with LogReader(plain) as log:
        assert log._summary is not None  # read whole to find the metadata
        assert log.metadata == fast and log.frame(log.first_frame + 5).keys() == frames.keys()
        assert log.collection == fast[topics.COLLECTION_METADATA]


def test_one_frame_is_read_without_reading_the_whole_file(collected_root: Path):
    path = _log(collected_root)
    io_counters = Path("/proc/self/io")
    if not io_counters.exists():
        pytest.skip("needs Linux /proc/self/io to count bytes read")

    def bytes_read() -> int:
        line = next(row for row in io_counters.read_text().splitlines() if row.startswith("rchar"))
        return int(line.split()[1])

    with LogReader(path) as log:
        before = bytes_read()
        messages = log.frame(20)
        spent = bytes_read() - before
        assert set(messages) == set(topics.per_frame_topics())
        assert messages[topics.EGO_STATE].frame == 20
    assert spent < path.stat().st_size / 3


def test_future_path_read_from_the_log_equals_the_scenarios(collected_root: Path):
    path = _log(collected_root)
    with LogReader(path) as log:
        scenario = store.read_scenario(collected_root, log.scenario_id)
        motion = ego_motion(scenario)
        for frame in (0, 3, 20):
            from_log, mask = log.future_path(frame)
            # the scenario's own path, cut where the log ends
            x, y, yaw = (a[: log.num_frames] for a in (motion.x_m, motion.y_m, motion.yaw_rad))
            expected, expected_mask = future_path(x, y, yaw, frame)
            assert (mask == expected_mask).all()
            assert np.allclose(from_log[mask], expected[mask], atol=1e-9)
        assert log.future_path(0)[1].all()  # 36 frames hold frame 0's whole 3 s future
        assert log.future_path(20)[1].tolist() == [True, True, True, False, False, False]
        states = log.ego_states()
    assert [s.frame for s in states] == list(range(36))
    assert np.allclose([s.x for s in states], motion.x_m[:36])
    assert [s.command for s in states] == motion.command[:36].tolist()


def test_lidar_points_in_the_log_carry_rings_and_surface_intensities(collected_root: Path):
    from drivee2e_data.logs.messages import LIDAR_DTYPE
    from drivee2e_data.sensors.lidar import INTENSITY, POINTS_PER_M

    with LogReader(_log(collected_root)) as log:
        cloud = log.frame(10, [topics.LIDAR])[topics.LIDAR]
        rig = log.rig["lidar"]["LIDAR_TOP"]
    points = np.frombuffer(cloud.data, LIDAR_DTYPE)
    xyz = np.stack([points["x"], points["y"], points["z"]], -1)
    assert np.linalg.norm(xyz, axis=1).max() <= rig["range_m"] + 1e-3
    assert points["ring"].max() <= rig["channels"] - 1
    # ring k's beams leave at its elevation: +10 deg for ring 0 down to -30 deg for ring 63, to
    # within what the points' grid moves them (half a step each way: at most sqrt(3) / 2048 m)
    distance = np.linalg.norm(xyz, axis=1)
    elevation = np.degrees(np.arcsin(xyz[:, 2] / distance))
    expected = np.linspace(10.0, -30.0, 64)[points["ring"]]
    grid = np.degrees(np.sqrt(3.0) / (2 * POINTS_PER_M) / distance)
    assert (np.abs(elevation - expected) < grid + 1e-3).all()
    assert np.median(np.abs(elevation - expected)) < 1e-2
    values = set(np.unique(points["intensity"]).tolist())
    assert {np.float32(INTENSITY[k]).item() for k in ("road", "road_mark")} <= values


def _pose(transform) -> np.ndarray:  # type: ignore[no-untyped-def]
    from drivee2e_data.geometry import rotation_from_quaternion

    rotation = transform.rotation
    matrix = np.eye(4)
    matrix[:3, :3] = rotation_from_quaternion([rotation.w, rotation.x, rotation.y, rotation.z])
    matrix[:3, 3] = (transform.translation.x, transform.translation.y, transform.translation.z)
    return matrix


def test_tf_puts_lidar_points_inside_the_boxes_that_count_them(collected_root: Path):
    from drivee2e_data.logs.messages import LIDAR_DTYPE
    from drivee2e_data.sensors.lidar_depth import NEAR_M
    from drivee2e_data.sensors.rig import default_rig
    from drivee2e_data.sensors.suite import BOX_POINT_MARGIN_M
    from drivee2e_data.sim.world import depth_step_m

    with LogReader(_log(collected_root)) as log:
        messages = log.frame(12, [topics.TF, topics.LIDAR, topics.OBJECTS])
        lidar_method = log.metadata[topics.COLLECTION_METADATA]["lidar"]
    poses = {
        (t.parent_frame_id, t.child_frame_id): _pose(t) for t in messages[topics.TF].transforms
    }
    lidar_to_world = poses[("world", "ego")] @ poses[("ego", "LIDAR_TOP")]
    points = np.frombuffer(messages[topics.LIDAR].data, LIDAR_DTYPE)
    xyz = np.stack([points["x"], points["y"], points["z"]], -1).astype(np.float64)
    world = xyz @ lidar_to_world[:3, :3].T + lidar_to_world[:3, 3]
    # hits lie on the box's faces: 2 mm of slack covers float32 points (ray casting), plus the
    # depth buffer's step at each point's range for a LiDAR read from depth images
    slack = np.full(len(xyz), 0.002 + BOX_POINT_MARGIN_M)
    if lidar_method == "depth":
        far_m = default_rig().lidar.range_m  # the depth views' far plane
        slack += depth_step_m(np.linalg.norm(xyz, axis=1), NEAR_M, far_m)
    counted = [o for o in messages[topics.OBJECTS].objects if o.num_lidar_points > 0]
    assert len(counted) >= 3
    for box in counted:
        # the box's own frame: x along its heading, origin at its centre
        c, s = np.cos(box.yaw), np.sin(box.yaw)
        relative = world - (box.x, box.y, box.z)
        local = np.stack(
            [
                c * relative[:, 0] + s * relative[:, 1],
                -s * relative[:, 0] + c * relative[:, 1],
                relative[:, 2],
            ],
            -1,
        )
        # a box counts its model's returns within BOX_POINT_MARGIN_M of its faces; the road seen
        # under a body (the models fill their boxes only partly) lies in the box too, but in
        # its bottom 5 cm
        half = np.array([box.length, box.width, box.height]) / 2
        inside = np.all(np.abs(local) <= half + slack[:, None], axis=1)
        above_road = inside & (local[:, 2] > -half[2] + 0.05)
        counted_here = box.num_lidar_points
        assert counted_here <= int(inside.sum()), box.instance_id
        # a road return grazing a box's lower edge may fall within the slack: allow a couple
        assert int(above_road.sum()) <= counted_here + max(2, counted_here // 100), box.instance_id
