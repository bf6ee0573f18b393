"""Plain data to protobuf messages: Foxglove schemas where one fits, `schemas` otherwise.
Every message carries the frame's timestamp; point clouds are in their sensor's frame."""

from __future__ import annotations

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from numpy.typing import NDArray

from drivee2e_data.geometry import quaternion_from_rotation, quaternion_from_yaw
from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.logs import schemas, topics
from drivee2e_data.sensors.ego_state import EgoMotion
from drivee2e_data.sensors.lidar import LidarSweep
from drivee2e_data.sensors.radar import RadarReturns
from drivee2e_data.sensors.rig import Camera
from drivee2e_data.sensors.suite import BoxAnnotation, SensorFrame
from drivee2e_data.sim.conditions import Exposure

_NUMERIC = {
    np.dtype("<f4"): PackedElementField.FLOAT32,
    np.dtype("u1"): PackedElementField.UINT8,
}
LIDAR_DTYPE = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("ring", "u1")]
)
RADAR_DTYPE = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("vx", "<f4"), ("vy", "<f4"), ("rcs", "<f4")]
)
# box colours in the scene view, by class (RGB 0..1)
CLASS_COLOURS = {
    "car": (0.2, 0.6, 1.0),
    "van": (0.3, 0.8, 1.0),
    "truck": (1.0, 0.6, 0.1),
    "bus": (1.0, 0.8, 0.1),
    "pedestrian": (1.0, 0.2, 0.3),
    "cyclist": (0.7, 0.3, 1.0),
    "tricyclist": (0.9, 0.4, 0.9),
    "motorcyclist": (0.5, 1.0, 0.3),
}


def _stamp(message, t_ns: int):  # type: ignore[no-untyped-def]
    message.timestamp.FromNanoseconds(int(t_ns))
    return message


def compressed_image(t_ns: int, frame_id: str, jpeg: bytes) -> CompressedImage:
    return _stamp(CompressedImage(frame_id=frame_id, data=jpeg, format="jpeg"), t_ns)


def png_image(t_ns: int, frame_id: str, png: bytes) -> CompressedImage:
    return _stamp(CompressedImage(frame_id=frame_id, data=png, format="png"), t_ns)


def camera_calibration(t_ns: int, camera: Camera) -> CameraCalibration:
    k = camera.intrinsic
    projection = np.hstack([k, np.zeros((3, 1))])
    return _stamp(
        CameraCalibration(
            frame_id=camera.name,
            width=camera.width,
            height=camera.height,
            distortion_model="plumb_bob",
            D=[0.0] * 5,
            K=k.ravel().tolist(),
            R=np.eye(3).ravel().tolist(),
            P=projection.ravel().tolist(),
        ),
        t_ns,
    )


def packed_cloud(t_ns: int, frame_id: str, rows: NDArray) -> PointCloud:
    """A PointCloud from a structured array (its fields and their offsets as they lie)."""
    cloud = PointCloud(frame_id=frame_id, point_stride=rows.dtype.itemsize, data=rows.tobytes())
    cloud.pose.orientation.w = 1.0
    for name in rows.dtype.names:
        dtype, offset = rows.dtype.fields[name][:2]
        cloud.fields.add(name=name, offset=offset, type=_NUMERIC[dtype])
    return _stamp(cloud, t_ns)


def lidar_cloud(t_ns: int, frame_id: str, sweep: LidarSweep) -> PointCloud:
    rows = np.empty(len(sweep.points_m), LIDAR_DTYPE)
    rows["x"], rows["y"], rows["z"] = sweep.points_m.T
    rows["intensity"], rows["ring"] = sweep.intensity, sweep.ring
    return packed_cloud(t_ns, frame_id, rows)


def radar_cloud(t_ns: int, frame_id: str, returns: RadarReturns) -> PointCloud:
    rows = np.empty(len(returns.points_m), RADAR_DTYPE)
    if len(rows):
        rows["x"], rows["y"], rows["z"] = returns.points_m.T
        rows["vx"], rows["vy"] = returns.velocity_comp_mps.T
        rows["rcs"] = returns.rcs_dbsm
    return packed_cloud(t_ns, frame_id, rows)


def _transform(t_ns: int, parent: str, child: str, pose: NDArray[np.float64]) -> FrameTransform:
    transform = _stamp(FrameTransform(parent_frame_id=parent, child_frame_id=child), t_ns)
    transform.translation.x, transform.translation.y, transform.translation.z = pose[:3, 3]
    w, x, y, z = quaternion_from_rotation(pose[:3, :3])
    rotation = transform.rotation
    rotation.w, rotation.x, rotation.y, rotation.z = w, x, y, z
    return transform


def frame_transforms(
    t_ns: int, ego_to_world: NDArray[np.float64], sensors: dict[str, NDArray[np.float64]]
) -> FrameTransforms:
    """World to ego, then ego to each sensor (`sensors`: name -> sensor-to-ego pose)."""
    message = FrameTransforms()
    message.transforms.append(_transform(t_ns, topics.WORLD_FRAME, topics.EGO_FRAME, ego_to_world))
    for name, sensor_to_ego in sensors.items():
        message.transforms.append(_transform(t_ns, topics.EGO_FRAME, name, sensor_to_ego))
    return message


def location_fix(t_ns: int, frame: SensorFrame, motion: EgoMotion) -> LocationFix:
    latitude, longitude, altitude = frame.gnss_lat_lon_alt
    index = frame.frame
    fix = LocationFix(
        frame_id=topics.EGO_FRAME,
        latitude=float(latitude),
        longitude=float(longitude),
        altitude=float(altitude),
        position_covariance_type=LocationFix.PositionCovarianceType.UNKNOWN,
        # compass heading: degrees clockwise from north
        heading=float(np.rad2deg(np.pi / 2 - motion.yaw_rad[index]) % 360.0),
    )
    fix.velocity.x, fix.velocity.y = motion.vx_mps[index], motion.vy_mps[index]
    return _stamp(fix, t_ns)


def camera_exposure(t_ns: int, camera: str, exposed: Exposure) -> schemas.CameraExposure:
    return _stamp(
        schemas.CameraExposure(frame_id=camera, gain=exposed.gain, metered=exposed.metered), t_ns
    )


def imu_message(t_ns: int, frame: SensorFrame) -> schemas.Imu:
    ax, ay, az = frame.imu_acceleration_mps2
    wx, wy, wz = frame.imu_angular_velocity_radps
    return _stamp(
        schemas.Imu(
            frame_id=topics.EGO_FRAME,
            linear_acceleration_x=ax,
            linear_acceleration_y=ay,
            linear_acceleration_z=az,
            angular_velocity_x=wx,
            angular_velocity_y=wy,
            angular_velocity_z=wz,
        ),
        t_ns,
    )


def ego_state(t_ns: int, motion: EgoMotion, index: int) -> schemas.EgoState:
    length, width, height = motion.size_m
    return _stamp(
        schemas.EgoState(
            frame=index,
            x=motion.x_m[index],
            y=motion.y_m[index],
            z=motion.z_m[index],
            yaw=motion.yaw_rad[index],
            vx=motion.vx_mps[index],
            vy=motion.vy_mps[index],
            speed=motion.speed_mps[index],
            acceleration=motion.acceleration_mps2[index],
            yaw_rate=motion.yaw_rate_radps[index],
            steer=motion.steer_rad[index],
            throttle=motion.throttle[index],
            brake=motion.brake[index],
            command=int(motion.command[index]),
            length=length,
            width=width,
            height=height,
            rear_axle_to_centre=motion.rear_axle_to_centre_m,
        ),
        t_ns,
    )


def _object(box: BoxAnnotation) -> schemas.Object:
    return schemas.Object(
        instance_id=box.track_id,
        category=box.category,
        blueprint=box.blueprint,
        length=box.size_m[0],
        width=box.size_m[1],
        height=box.size_m[2],
        x=box.centre_world_m[0],
        y=box.centre_world_m[1],
        z=box.centre_world_m[2],
        yaw=box.yaw_world_rad,
        vx=box.velocity_world_mps[0],
        vy=box.velocity_world_mps[1],
        ego_x=box.centre_ego_m[0],
        ego_y=box.centre_ego_m[1],
        ego_z=box.centre_ego_m[2],
        ego_yaw=box.yaw_ego_rad,
        ego_vx=box.velocity_ego_mps[0],
        ego_vy=box.velocity_ego_mps[1],
        visibility=box.visibility,
        visible_share=box.visible_share,
        cameras=list(box.cameras),
        num_lidar_points=box.num_lidar_points,
        num_radar_points=box.num_radar_points,
    )


def object_annotations(t_ns: int, frame: SensorFrame) -> schemas.ObjectAnnotations:
    message = _stamp(schemas.ObjectAnnotations(frame=frame.frame), t_ns)
    message.objects.extend(_object(box) for box in frame.boxes)
    return message


def scene_boxes(t_ns: int, frame: SensorFrame) -> SceneUpdate:
    """The annotated boxes as cubes in the world frame, coloured by class, with their ids."""
    update = SceneUpdate()
    for box in frame.boxes:
        entity = update.entities.add(id=box.track_id, frame_id=topics.WORLD_FRAME)
        entity.timestamp.FromNanoseconds(int(t_ns))
        entity.lifetime.FromNanoseconds(150_000_000)  # until the next frame's boxes
        entity.metadata.add(key="category", value=box.category)
        cube = entity.cubes.add()
        cube.pose.position.x, cube.pose.position.y, cube.pose.position.z = box.centre_world_m
        w, _, _, z = quaternion_from_yaw(box.yaw_world_rad)
        cube.pose.orientation.w, cube.pose.orientation.z = w, z
        cube.size.x, cube.size.y, cube.size.z = box.size_m
        red, green, blue = CLASS_COLOURS[box.category]
        cube.color.CopyFrom(Color(r=red, g=green, b=blue, a=0.45))
    return update


def signal_lanes(intersection_map: IntersectionMap) -> dict[str, list[str]]:
    """Lane ids by the signal that controls them."""
    lanes: dict[str, list[str]] = {}
    for lane in intersection_map.lanes:
        if lane.signal_id is not None:
            lanes.setdefault(lane.signal_id, []).append(lane.lane_id)
    return lanes


def traffic_lights(
    t_ns: int, frame: SensorFrame, lanes: dict[str, list[str]], ego_signal_id: str | None = None
) -> schemas.TrafficLights:
    """Every signal's state at the frame with the lanes it controls (`signal_lanes`), and the
    signal that binds the ego (`binding.binding_signals`; none: '')."""
    message = _stamp(schemas.TrafficLights(), t_ns)
    message.ego_signal_id = ego_signal_id or ""
    for signal_id, state in sorted(frame.signals.items()):
        message.lights.add(
            signal_id=signal_id, state=state.name, controlled_lane_ids=lanes.get(signal_id, [])
        )
    return message


def map_scene(t_ns: int, intersection_map: IntersectionMap) -> SceneUpdate:
    """Lane boundaries, crosswalks and stop lines as lines in the world frame, shown for good."""
    update = SceneUpdate()
    entity = update.entities.add(id=f"map/{intersection_map.map_id}", frame_id=topics.WORLD_FRAME)
    entity.timestamp.FromNanoseconds(int(t_ns))
    entity.frame_locked = True
    white, yellow, red = Color(r=0.9, g=0.9, b=0.9, a=1), Color(r=1, g=0.85, a=1), Color(r=1, a=1)

    def line(points: NDArray[np.float64], color: Color, kind: int, thickness: float) -> None:
        primitive = entity.lines.add(type=kind, thickness=thickness, scale_invariant=True)
        primitive.pose.orientation.w = 1.0
        primitive.color.CopyFrom(color)
        for x, y in np.asarray(points)[:, :2]:
            primitive.points.add(x=float(x), y=float(y), z=0.02)

    for lane in intersection_map.lanes:
        line(lane.left_boundary_m, white, LinePrimitive.LINE_STRIP, 1.0)
        line(lane.right_boundary_m, white, LinePrimitive.LINE_STRIP, 1.0)
    for crosswalk in intersection_map.crosswalks:
        line(crosswalk.polygon_m, yellow, LinePrimitive.LINE_LOOP, 2.0)
    for stop_line in intersection_map.stop_lines:
        line(stop_line.line_m, red, LinePrimitive.LINE_STRIP, 3.0)
    return update
